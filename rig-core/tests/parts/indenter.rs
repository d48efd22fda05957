//! Indenters: every built-in loads and rasterises, the analytic faces match their formulas, STL
//! meshes rasterise to the expected heights, and malformed input is named.

use rig_core::indenter::{Centre, Indenter, IndenterError, StlOptions, TipDirection};

fn repo_file(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel)
}

/// A scratch directory removed on drop (no extra dev-dependency needed).
struct Scratch(std::path::PathBuf);

impl Scratch {
    fn new(tag: &str) -> Self {
        let dir =
            std::env::temp_dir().join(format!("rig-core-indenter-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn all_nineteen_builtins_load_and_rasterise_without_nan() {
    let names = Indenter::list_builtin();
    assert_eq!(names.len(), 19);
    for expected in [
        "cone",
        "cylinder",
        "cylinder_sh",
        "cylinder_si",
        "dotin",
        "dots",
        "hemisphere",
        "hexagon",
        "line",
        "moon",
        "pacman",
        "prism",
        "random",
        "sphere",
        "sphere_s",
        "torus",
        "triangle",
        "wave",
        "paralines",
    ] {
        assert!(names.contains(&expected), "{expected} missing");
    }
    for name in names {
        let ind = Indenter::builtin(name).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(ind.name(), *name, "name inside {name}.toml");
        assert!(!ind.description().is_empty(), "{name} has no description");
        assert_eq!(ind.footprint_mm(), [16.0, 16.0]);
        for res in [0.5, 0.1] {
            let map = ind.heightmap(res, (16.0, 16.0));
            assert_eq!(map.nx, (16.0_f64 / res).round() as usize);
            assert!(
                map.gap_mm.iter().all(|g| !g.is_nan()),
                "{name} at {res}: NaN"
            );
            assert!(
                map.gap_mm.iter().all(|&g| g >= 0.0),
                "{name} at {res}: negative"
            );
            assert!(map.material_cells() > 0, "{name} at {res}: empty");
            // The lowest point is 0; the grid may miss the exact tip by up to a cell (slopes ≤ 1).
            assert!(
                map.min_gap_mm() < res,
                "{name} at {res}: min {}",
                map.min_gap_mm()
            );
        }
        // The builtin files on disk are the same ones that are embedded.
        let from_disk = Indenter::load(
            repo_file(&format!("indenters/{name}.toml"))
                .to_str()
                .unwrap(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            from_disk.heightmap(0.5, (16.0, 16.0)),
            ind.heightmap(0.5, (16.0, 16.0))
        );
    }
}

#[test]
fn load_resolves_names_to_builtins() {
    assert_eq!(Indenter::load("cone").unwrap().name(), "cone");
}

#[test]
fn unknown_name_lists_the_builtins() {
    let e = Indenter::load("spoon").unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, IndenterError::Unknown { .. }));
    assert!(msg.contains("`spoon`"), "{msg}");
    for name in Indenter::list_builtin() {
        assert!(msg.contains(name), "{msg}");
    }
}

#[test]
fn sphere_matches_the_cap_formula() {
    for name in ["sphere", "sphere_s", "hemisphere"] {
        let ind = Indenter::builtin(name).unwrap();
        let rim = match ind.geometry() {
            rig_core::indenter::Geometry::Shapes(s) => match &s[0].primitive {
                rig_core::indenter::Primitive::SphereCap(c) => c.radius_mm,
                other => panic!("{name} is {other:?}"),
            },
            other => panic!("{name} is {other:?}"),
        };
        let r_sphere = rim;
        let res = 0.1;
        let map = ind.heightmap(res, (16.1, 16.1)); // 161 cells: one centred on the axis
        assert_eq!(map.get(80, 80), Some(0.0));
        for iy in 0..map.ny {
            for ix in 0..map.nx {
                let r = map.x_mm(ix).hypot(map.y_mm(iy));
                let g = map.get(ix, iy).unwrap();
                if r < r_sphere - res {
                    let expected = r_sphere - (r_sphere * r_sphere - r * r).sqrt();
                    assert!(
                        (g - expected).abs() < 1e-9,
                        "{name} r={r}: {g} vs {expected}"
                    );
                } else if r > r_sphere + res {
                    assert!(g.is_infinite(), "{name} r={r}: {g}");
                }
            }
        }
    }
    // sphere_s is the small one.
    let small = Indenter::builtin("sphere_s")
        .unwrap()
        .heightmap(0.1, (16.0, 16.0));
    let big = Indenter::builtin("sphere")
        .unwrap()
        .heightmap(0.1, (16.0, 16.0));
    assert!(small.material_cells() < big.material_cells());
}

#[test]
fn cone_matches_r_over_tan_alpha() {
    let ind = Indenter::builtin("cone").unwrap();
    let alpha = 60f64.to_radians();
    let map = ind.heightmap(0.2, (16.2, 16.2));
    for iy in 0..map.ny {
        for ix in 0..map.nx {
            let r = map.x_mm(ix).hypot(map.y_mm(iy));
            let g = map.get(ix, iy).unwrap();
            if r <= 5.8 {
                assert!((g - r / alpha.tan()).abs() < 1e-9, "r={r}: {g}");
            } else if r > 6.2 {
                assert!(g.is_infinite());
            }
        }
    }
    // Point queries agree with the grid.
    assert!((ind.gap_mm(3.0, 4.0) - 5.0 / alpha.tan()).abs() < 1e-12);
}

#[test]
fn composite_and_flat_faces() {
    // dotin: the ring and the central dot are both at gap 0; the gap between them is empty.
    let dotin = Indenter::builtin("dotin").unwrap();
    assert_eq!(dotin.gap_mm(0.0, 0.0), 0.0);
    assert_eq!(dotin.gap_mm(4.5, 0.0), 0.0);
    assert!(dotin.gap_mm(2.5, 0.0).is_infinite());
    // pacman: the mouth opens towards +x.
    let pac = Indenter::builtin("pacman").unwrap();
    assert!(pac.gap_mm(3.0, 0.0).is_infinite());
    assert_eq!(pac.gap_mm(-3.0, 0.0), 0.0);
    // wave: crest at x = 0, trough half a wavelength away.
    let wave = Indenter::builtin("wave").unwrap();
    assert!(wave.gap_mm(0.0, 3.0).abs() < 1e-12);
    assert!((wave.gap_mm(2.0, 0.0) - 1.0).abs() < 1e-12);
    // paralines: five lines 2.5 mm apart.
    let pl = Indenter::builtin("paralines").unwrap();
    for k in -2..=2 {
        assert_eq!(pl.gap_mm(0.0, f64::from(k) * 2.5), 0.0);
    }
    assert!(pl.gap_mm(0.0, 1.25).is_infinite());
    // random: reproducible, lowest point at 0.
    let a = Indenter::builtin("random")
        .unwrap()
        .heightmap(0.05, (16.0, 16.0));
    let b = Indenter::builtin("random")
        .unwrap()
        .heightmap(0.05, (16.0, 16.0));
    assert_eq!(a, b);
}

#[test]
fn lifted_shapes_are_measured_from_the_lowest_point() {
    let ind = Indenter::from_toml_str(
        r#"
        name = "steps"
        [[shape]]
        kind = "flat_punch"
        radius_mm = 1.0
        lift_mm = 0.5
        [[shape]]
        kind = "ring"
        outer_radius_mm = 3.0
        inner_radius_mm = 2.0
        lift_mm = 0.2
        "#,
    )
    .unwrap();
    assert!((ind.gap_mm(0.0, 0.0) - 0.3).abs() < 1e-12);
    assert_eq!(ind.gap_mm(2.5, 0.0), 0.0);
}

#[test]
fn bad_grid_requests_are_errors_not_panics() {
    let ind = Indenter::builtin("cone").unwrap();
    assert!(ind.try_heightmap(0.0, (16.0, 16.0)).is_err());
    assert!(ind.try_heightmap(f64::NAN, (16.0, 16.0)).is_err());
    assert!(ind.try_heightmap(0.1, (-1.0, 16.0)).is_err());
    assert!(ind.try_heightmap(1e-6, (16.0, 16.0)).is_err());
}

#[test]
fn malformed_toml_is_named() {
    let e = Indenter::from_toml_str("name = \"x\"\n[[shape]]\nkind = \"cone\"\nradius_mm = 2.0\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("shape[0]") && e.contains("semi_angle_deg"),
        "{e}"
    );

    let e = Indenter::from_toml_str(
        "name = \"x\"\n[[shape]]\nkind = \"cone\"\nsemi_angle_deg = 60.0\nradius_mm = 2.0\nradious = 1\n",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("shape[0]") && e.contains("unknown field `radious`"),
        "{e}"
    );

    let e = Indenter::from_toml_str("name = \"x\"\n[[shape]]\nkind = \"blob\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("blob") && e.contains("sphere_cap"), "{e}");

    let e = Indenter::from_toml_str(
        "name = \"x\"\n[[shape]]\nkind = \"cone\"\nsemi_angle_deg = 95.0\nradius_mm = 2.0\n",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("shape[0].semi_angle_deg"), "{e}");

    let e = Indenter::from_toml_str(
        "name = \"x\"\n[[shape]]\nkind = \"flat_punch\"\nradius_mm = 9.0\n",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("shape[0]") && e.contains("footprint_mm"), "{e}");

    let e = Indenter::from_toml_str(
        "name = \"x\"\ncolour = \"red\"\n[[shape]]\nkind = \"flat_punch\"\nradius_mm = 1.0\n",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("colour") && e.contains("line 2"), "{e}");

    let e = Indenter::from_toml_str("name = \"x\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("no geometry"), "{e}");

    let e = Indenter::from_toml_str(
        "name = \"a b\"\n[[shape]]\nkind = \"flat_punch\"\nradius_mm = 1.0\n",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("name"), "{e}");

    let e = Indenter::from_toml_str("name = [").unwrap_err();
    assert!(matches!(e, IndenterError::Toml { .. }), "{e:?}");
}

// ---- STL ----------------------------------------------------------------------------------

type Tri = [[f32; 3]; 3];

fn binary_stl(tris: &[Tri]) -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out[..5].copy_from_slice(b"solid"); // binary files may start with "solid" too
    out.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        out.extend_from_slice(&[0u8; 12]); // normal, ignored
        for v in t {
            for c in v {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}

fn ascii_stl(tris: &[Tri]) -> String {
    let mut s = String::from("solid test\n");
    for t in tris {
        s.push_str("  facet normal 0 0 0\n    outer loop\n");
        for v in t {
            s.push_str(&format!("      vertex {} {} {}\n", v[0], v[1], v[2]));
        }
        s.push_str("    endloop\n  endfacet\n");
    }
    s.push_str("endsolid test\n");
    s
}

/// Axis-aligned cube `[x0, x0 + side]^2 × [z0, z0 + side]`, 12 triangles.
fn cube(x0: f32, z0: f32, side: f32) -> Vec<Tri> {
    let (a, b) = (x0, x0 + side);
    let (lo, hi) = (z0, z0 + side);
    let p = |x, y, z| [x, y, z];
    let quads = [
        [p(a, a, lo), p(b, a, lo), p(b, b, lo), p(a, b, lo)], // bottom
        [p(a, a, hi), p(a, b, hi), p(b, b, hi), p(b, a, hi)], // top
        [p(a, a, lo), p(a, a, hi), p(b, a, hi), p(b, a, lo)],
        [p(b, a, lo), p(b, a, hi), p(b, b, hi), p(b, b, lo)],
        [p(b, b, lo), p(b, b, hi), p(a, b, hi), p(a, b, lo)],
        [p(a, b, lo), p(a, b, hi), p(a, a, hi), p(a, a, lo)],
    ];
    quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect()
}

#[test]
fn binary_cube_rasterises_to_a_flat_punch() {
    // A 4 mm cube somewhere in space: centred on its bbox and dropped to z = 0 when loaded.
    let bytes = binary_stl(&cube(10.0, 5.0, 4.0));
    let ind = Indenter::from_stl_bytes("cube", &bytes, StlOptions::default()).unwrap();
    assert_eq!(ind.footprint_mm(), [4.0, 4.0]);
    assert_eq!(ind.height_mm(), 4.0);
    let map = ind.heightmap(0.5, (8.0, 8.0)); // centres at ±0.25 … ±3.75
    for iy in 0..map.ny {
        for ix in 0..map.nx {
            let inside = map.x_mm(ix).abs() < 2.0 && map.y_mm(iy).abs() < 2.0;
            let g = map.get(ix, iy).unwrap();
            if inside {
                assert_eq!(g, 0.0, "({ix}, {iy})");
            } else {
                assert!(g.is_infinite(), "({ix}, {iy}): {g}");
            }
        }
    }
    assert_eq!(map.material_cells(), 64);
    // Turned over (+z tip), the cube's face is the same.
    let opts = StlOptions {
        tip: TipDirection::PlusZ,
        ..StlOptions::default()
    };
    let flipped = Indenter::from_stl_bytes("cube", &bytes, opts).unwrap();
    assert_eq!(flipped.heightmap(0.5, (8.0, 8.0)), map);
}

#[test]
fn ascii_tetrahedron_rasterises_to_its_planes() {
    // Regular-base tetrahedron, apex down at the origin, base triangle (circumradius a) at z = h.
    let (a, h) = (4.0f32, 3.0f32);
    let s3 = 3f32.sqrt();
    let apex = [0.0, 0.0, 0.0];
    let b0 = [a, 0.0, h];
    let b1 = [-a / 2.0, a * s3 / 2.0, h];
    let b2 = [-a / 2.0, -a * s3 / 2.0, h];
    let tris = vec![[apex, b1, b0], [apex, b2, b1], [apex, b0, b2], [b0, b1, b2]];
    let text = ascii_stl(&tris);
    let opts = StlOptions {
        centre: Centre::Origin,
        ..StlOptions::default()
    };
    let ind = Indenter::from_stl_bytes("tetra", text.as_bytes(), opts).unwrap();

    // The lower surface is the apex cone of the three side faces: z = h · max_k(n_k · p) / apothem,
    // n_k the outward normals of the base edges (at 60°, 180°, 300°), apothem a / 2.
    let expected = |x: f64, y: f64| -> f64 {
        (0..3)
            .map(|k| {
                let phi = (60.0 + 120.0 * f64::from(k)).to_radians();
                x * phi.cos() + y * phi.sin()
            })
            .fold(f64::NEG_INFINITY, f64::max)
            * f64::from(h)
            / (f64::from(a) / 2.0)
    };
    let map = ind.heightmap(0.25, (10.0, 10.0));
    let mut checked = 0;
    for iy in 0..map.ny {
        for ix in 0..map.nx {
            let (x, y) = (map.x_mm(ix), map.y_mm(iy));
            let g = map.get(ix, iy).unwrap();
            let e = expected(x, y);
            if e < f64::from(h) - 0.05 {
                assert!((g - e).abs() < 1e-5, "({x}, {y}): {g} vs {e}");
                checked += 1;
            } else if e > f64::from(h) + 0.05 {
                assert!(g.is_infinite(), "({x}, {y}): {g}");
            }
        }
    }
    assert!(checked > 100);
    // Point query at the apex.
    assert!(ind.gap_mm(0.0, 0.0).abs() < 1e-9);
}

#[test]
fn stl_files_load_directly_and_through_toml() {
    let dir = Scratch::new("stl");
    let stl_path = dir.0.join("my cube.stl");
    std::fs::write(&stl_path, binary_stl(&cube(0.0, 0.0, 2.0))).unwrap();
    let ind = Indenter::load(stl_path.to_str().unwrap()).unwrap();
    assert_eq!(ind.name(), "my_cube");
    assert_eq!(ind.gap_mm(0.0, 0.0), 0.0);

    let toml_path = dir.0.join("wrapped.toml");
    std::fs::write(
        &toml_path,
        "name = \"wrapped\"\ndescription = \"a cube in metres\"\n[stl]\npath = \"m.stl\"\nmm_per_unit = 1000.0\n",
    )
    .unwrap();
    std::fs::write(dir.0.join("m.stl"), ascii_stl(&cube(0.0, 0.0, 0.002))).unwrap();
    let ind = Indenter::load(toml_path.to_str().unwrap()).unwrap();
    assert_eq!(ind.description(), "a cube in metres");
    assert!((ind.footprint_mm()[0] - 2.0).abs() < 1e-6);
    assert_eq!(ind.gap_mm(0.9, -0.9), 0.0);
    assert!(ind.gap_mm(1.1, 0.0).is_infinite());
}

#[test]
fn malformed_stl_is_named() {
    let err = |bytes: &[u8]| {
        Indenter::from_stl_bytes("bad", bytes, StlOptions::default())
            .unwrap_err()
            .to_string()
    };
    // Binary header announcing more triangles than present.
    let mut bytes = binary_stl(&cube(0.0, 0.0, 1.0));
    bytes.truncate(bytes.len() - 10);
    let e = err(&bytes);
    assert!(e.contains("announces 12 triangles"), "{e}");
    // Too short for anything.
    assert!(err(b"hello").contains("too short"));
    // ASCII with a broken number, with its line.
    let text = ascii_stl(&cube(0.0, 0.0, 1.0)).replacen("vertex 0 0 0", "vertex 0 zero 0", 1);
    let e = err(text.as_bytes());
    assert!(e.contains("line 4") && e.contains("`zero`"), "{e}");
    // ASCII facet with two vertices.
    let e = err(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\nendsolid\n");
    assert!(e.contains("2 vertices"), "{e}");
    // Truncated ASCII.
    let e = err(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n");
    assert!(e.contains("truncated"), "{e}");
    // Empty solid.
    assert!(err(b"solid x\nendsolid x\n").contains("no triangles"));
    // Only vertical faces.
    let wall: Vec<Tri> = vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1.0]]];
    assert!(err(&binary_stl(&wall)).contains("vertical"));
    // NaN coordinate.
    let nan: Vec<Tri> = vec![[[f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]];
    assert!(err(&binary_stl(&nan)).contains("non-finite"));
    // Missing file.
    let e = Indenter::load("/nonexistent/tip.stl")
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/tip.stl"), "{e}");
}

/// Every built-in face that knows its edge: inside (distance > 0) the face is there and its
/// gap is `gap_mm`'s, outside it is not, and the distance changes no faster than the point
/// moves (it is a distance, so the contact's filter across a wall is one sub-sample wide).
#[test]
fn edges_agree_with_the_faces_and_are_distances() {
    let step = 0.0137;
    for name in Indenter::list_builtin() {
        let ind = Indenter::builtin(name).unwrap();
        if *name == "random" {
            assert!(ind.edge_mm(0.0, 0.0).is_none());
            continue;
        }
        let [fx, fy] = ind.footprint_mm();
        let (nx, ny) = ((fx / step) as i64 / 2 + 4, (fy / step) as i64 / 2 + 4);
        let (mut inside, mut outside) = (0, 0);
        for iy in -ny..=ny {
            for ix in -nx..=nx {
                let (x, y) = (ix as f64 * step, iy as f64 * step);
                let (g, d) = ind.edge_mm(x, y).unwrap();
                let gap = ind.gap_mm(x, y);
                if d > 1e-9 {
                    inside += 1;
                    assert!(
                        (gap - g).abs() < 1e-9,
                        "{name} at ({x}, {y}): {d} mm inside, gap {gap} against {g}"
                    );
                } else if d < -1e-9 {
                    outside += 1;
                    assert!(
                        gap.is_infinite(),
                        "{name} at ({x}, {y}): {d} mm outside, gap {gap}"
                    );
                }
                let (_, dx) = ind.edge_mm(x + step, y).unwrap();
                let (_, dy) = ind.edge_mm(x, y + step).unwrap();
                assert!(
                    (dx - d).abs() <= step * (1.0 + 1e-9) && (dy - d).abs() <= step * (1.0 + 1e-9),
                    "{name} at ({x}, {y}): the distance {d} moves to {dx} / {dy} over {step} mm"
                );
            }
        }
        assert!(
            inside > 100 && outside > 100,
            "{name}: {inside} inside, {outside} outside"
        );
    }
}
