//! Hard cases stay finite and sensible, and bad input is an error, never a panic.

use std::sync::Arc;

use hardware_mocks::sim::{ContactModel, IndenterPose, Scene, SimError, SimOutput, simulate};
use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;

fn scene(name: &str, model: ContactModel, depth: f64) -> Scene {
    let mut s = Scene::new(
        ElastomerConfig::default(),
        Arc::new(Indenter::builtin(name).unwrap()),
        IndenterPose {
            depth_mm: depth,
            ..IndenterPose::default()
        },
    );
    s.effects.contact = model;
    s.effects.cell_mm = Some(0.2);
    s.effects.surface_field = true;
    s
}

fn sane(out: &SimOutput) {
    assert!(out.wrench.is_finite(), "{:?}", out.wrench);
    assert!(out.wrench.force_n[2] <= 0.0, "pressing never pulls");
    assert!(out.stats.converged);
    if let Some(f) = &out.field {
        for v in [&f.uz_mm, &f.ux_mm, &f.uy_mm, &f.pressure_mpa] {
            assert!(v.iter().all(|x| x.is_finite()));
        }
        assert!(f.pressure_mpa.iter().all(|&p| p >= 0.0));
    }
}

#[test]
fn zero_depth_gives_zero_force_and_a_flat_field() {
    for model in ContactModel::ALL {
        for depth in [0.0, -0.3] {
            let out = simulate(&scene("sphere", model, depth)).unwrap();
            sane(&out);
            assert_eq!(out.wrench.to_array(), [0.0; 6], "{model}");
            assert_eq!(out.stats.normal_solves, 0);
            let f = out.field.unwrap();
            assert!(f.uz_mm.iter().all(|&u| u == 0.0));
        }
    }
}

#[test]
fn contact_touching_the_gel_edge() {
    let centred = simulate(&scene("sphere", ContactModel::Layer, 0.5)).unwrap();
    let mut s = scene("sphere", ContactModel::Layer, 0.5);
    s.pose.contact_mm = [4.9, 0.0]; // axis 0.1 mm inside the +x edge
    let edge = simulate(&s).unwrap();
    sane(&edge);
    let (fc, fe) = (-centred.wrench.force_n[2], -edge.wrench.force_n[2]);
    // About half the contact is cut off by the edge.
    assert!(fe > 0.2 * fc && fe < 0.8 * fc, "{fe} vs {fc}");
    // The force acts near the edge: a torque about the contact point stays small,
    // Ty = −Σ (x − cx) fz with the load left of the axis.
    assert!(edge.wrench.torque_nmm[1].abs() < fe * 1.5);
    // Completely off the gel: no contact.
    s.pose.contact_mm = [9.0, 0.0];
    let off = simulate(&s).unwrap();
    assert_eq!(off.wrench.force_n, [0.0; 3]);
}

#[test]
fn paralines_covering_the_whole_gel() {
    for model in [
        ContactModel::Winkler,
        ContactModel::HalfSpace,
        ContactModel::Layer,
    ] {
        let out = simulate(&scene("paralines", model, 0.5)).unwrap();
        sane(&out);
        // Five 1 mm bars across the 10 mm gel: about 5 × 1 × 8 mm² minus the cut ends.
        assert!(
            out.contact_area_mm2 > 25.0,
            "{model}: {}",
            out.contact_area_mm2
        );
        assert!(out.wrench.force_n[2] < 0.0);
    }
}

#[test]
fn sharp_cone_tip_and_tiny_sphere() {
    for (name, depth) in [
        ("cone", 0.01),
        ("cone", 0.05),
        ("sphere_s", 0.02),
        ("sphere_s", 0.3),
    ] {
        for model in [ContactModel::HalfSpace, ContactModel::Layer] {
            let mut s = scene(name, model, depth);
            s.effects.cell_mm = Some(0.1);
            let out = simulate(&s).unwrap();
            sane(&out);
            // A 0.01 mm cone press touches less than a cell (the tip lies between cell
            // centres): it may read zero, but never more than a whisker.
            if depth < 0.02 {
                assert!(out.wrench.force_n[2] > -1e-3, "{name} {depth} {model}");
            } else {
                assert!(out.wrench.force_n[2] < 0.0, "{name} {depth} {model}");
            }
        }
    }
    // The tiny sphere against Hertz when it spans a few cells: a = 0.77 mm at 0.3 mm.
    let mut s = scene("sphere_s", ContactModel::HalfSpace, 0.3);
    s.effects.cell_mm = Some(0.1);
    let f = -simulate(&s).unwrap().wrench.force_n[2];
    s.effects.contact = ContactModel::Hertz;
    let hertz = -simulate(&s).unwrap().wrench.force_n[2];
    assert!((f - hertz).abs() / hertz < 0.03, "{f} vs {hertz}");
}

#[test]
fn depth_beyond_the_gel_thickness_is_a_clear_error() {
    let err = simulate(&scene("sphere", ContactModel::Layer, 3.5)).unwrap_err();
    assert!(matches!(err, SimError::DepthBeyondThickness { .. }));
    assert!(err.to_string().contains("thickness"), "{err}");
}

#[test]
fn very_small_and_very_large_moduli_scale_linearly() {
    let base = simulate(&scene("cone", ContactModel::Layer, 0.5)).unwrap();
    for e in [1e-3, 1e3] {
        let mut s = scene("cone", ContactModel::Layer, 0.5);
        s.elastomer.youngs_modulus_mpa = e;
        let out = simulate(&s).unwrap();
        sane(&out);
        let ratio = out.wrench.force_n[2] / base.wrench.force_n[2];
        let want = e / ElastomerConfig::default().youngs_modulus_mpa;
        assert!((ratio - want).abs() / want < 1e-6, "E = {e}: {ratio}");
    }
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let mut s = scene("sphere", ContactModel::Layer, f64::NAN);
    assert!(simulate(&s).is_err());
    s.pose.depth_mm = 0.5;
    for cell in [0.0, -1.0, f64::INFINITY, 1e-5] {
        s.effects.cell_mm = Some(cell);
        assert!(simulate(&s).is_err(), "cell {cell}");
    }
    s.effects.cell_mm = Some(0.2);
    s.elastomer.poisson_ratio = 0.5;
    assert!(simulate(&s).is_err());
    s.elastomer.poisson_ratio = 0.49;
    s.elastomer.youngs_modulus_mpa = -1.0;
    assert!(simulate(&s).is_err());
    // Hertz pressed past its cap's rim.
    let mut cap = Scene::new(
        ElastomerConfig::default(),
        Arc::new(
            Indenter::from_toml_str(
                "name = \"cap\"\n[[shape]]\nkind = \"sphere_cap\"\nradius_mm = 4.0\nrim_radius_mm = 1.0\n",
            )
            .unwrap(),
        ),
        IndenterPose {
            depth_mm: 0.5,
            ..IndenterPose::default()
        },
    );
    cap.effects.contact = ContactModel::Hertz;
    assert!(matches!(simulate(&cap), Err(SimError::NotASphere { .. })));
}

#[test]
fn every_builtin_indenter_is_finite() {
    for name in Indenter::list_builtin() {
        let out = simulate(&scene(name, ContactModel::Layer, 0.4)).unwrap();
        sane(&out);
        assert!(out.wrench.force_n[2] < 0.0, "{name}");
    }
}
