//! The tape file: one contact episode's steps (time, position, wrench) and its surface fields,
//! written once and read back step by step.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::{Arc, Mutex};

use crate::rig_sim::lock::lock;
use crate::sim::{SimOutput, SurfaceField};

/// Field values below this (mm) are not kept (see the tape module's docs).
pub const CROP_MM: f64 = 1e-5;
/// A tape file's first bytes.
const MAGIC: &[u8; 8] = b"RIGTAPE1";
/// Bytes of one step's record in a tape file.
const STEP_BYTES: usize = 8 + 3 * 8 + 6 * 8 + 8 + 4;

/// One recorded step.
#[derive(Debug, Clone, Copy)]
pub(super) struct TapeStep {
    /// Clock time since the episode's first step, ns.
    pub(super) t_ns: u64,
    /// Indenter position: axis x, y and depth, mm.
    pub(super) at: [f64; 3],
    /// The simulator's wrench (about the contact point), Fx..Mz.
    pub(super) w: [f64; 6],
    /// Offset and length of the step's field in the file (length 0: none).
    pub(super) field: (u64, u32),
}

/// A tape on disk: its step table in memory, its fields read when needed.
pub(super) struct Tape {
    pub(super) steps: Vec<TapeStep>,
    pub(super) file: File,
    /// The last field decoded (replays read each field for several steps).
    pub(super) decoded: Mutex<Option<(usize, Arc<SurfaceField>)>>,
}

impl Tape {
    pub(super) fn load(path: &Path) -> io::Result<Tape> {
        let mut file = File::open(path)?;
        let mut head = [0u8; 12];
        file.read_exact(&mut head)?;
        if &head[..8] != MAGIC {
            return Err(bad("not a contact tape"));
        }
        let n = u32::from_le_bytes(head[8..12].try_into().expect("4 bytes")) as usize;
        if n == 0 || n > 10_000_000 {
            return Err(bad("implausible step count"));
        }
        let mut table = vec![0u8; n * STEP_BYTES];
        file.read_exact(&mut table)?;
        let len = file.metadata()?.len();
        let steps = table
            .chunks_exact(STEP_BYTES)
            .map(|c| {
                let mut r = Reader(c);
                let t_ns = r.u64();
                let at = [r.f64(), r.f64(), r.f64()];
                let w = std::array::from_fn(|_| r.f64());
                let field = (r.u64(), r.u32());
                TapeStep { t_ns, at, w, field }
            })
            .collect::<Vec<_>>();
        for s in &steps {
            let finite = s.at.iter().chain(&s.w).all(|v| v.is_finite());
            if !finite || s.field.0 + s.field.1 as u64 > len {
                return Err(bad("damaged step table"));
            }
        }
        Ok(Tape {
            steps,
            file,
            decoded: Mutex::new(None),
        })
    }

    pub(super) fn has_fields(&self) -> bool {
        self.steps.iter().all(|s| s.field.1 > 0)
    }

    /// The field of step `k` (`None`: the step kept none).
    pub(super) fn field(&self, k: usize) -> io::Result<Option<Arc<SurfaceField>>> {
        let (off, len) = self.steps[k].field;
        if len == 0 {
            return Ok(None);
        }
        let mut memo = lock(&self.decoded);
        if let Some((i, f)) = memo.as_ref()
            && *i == k
        {
            return Ok(Some(f.clone()));
        }
        let mut buf = vec![0u8; len as usize];
        self.file.read_exact_at(&mut buf, off)?;
        let f = Arc::new(decode_field(&buf)?);
        *memo = Some((k, f.clone()));
        Ok(Some(f))
    }
}

/// A live episode being recorded.
pub(super) struct TapeRecorder {
    pub(super) steps: Vec<TapeStep>,
    pub(super) fields: Vec<u8>,
}

impl TapeRecorder {
    pub(super) fn push(&mut self, t_ns: u64, at: [f64; 3], out: &SimOutput) {
        let field = match &out.field {
            Some(f) => {
                let off = self.fields.len() as u64;
                encode_field(f, &mut self.fields);
                (off, (self.fields.len() as u64 - off) as u32)
            }
            None => (0, 0),
        };
        self.steps.push(TapeStep {
            t_ns,
            at,
            w: out.wrench.to_array(),
            field,
        });
    }

    pub(super) fn write(&self, path: &Path) -> io::Result<()> {
        let base = (12 + self.steps.len() * STEP_BYTES) as u64;
        let mut out = Vec::with_capacity(base as usize + self.fields.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(self.steps.len() as u32).to_le_bytes());
        for s in &self.steps {
            out.extend_from_slice(&s.t_ns.to_le_bytes());
            for v in s.at.iter().chain(&s.w) {
                out.extend_from_slice(&v.to_le_bytes());
            }
            let off = if s.field.1 > 0 { base + s.field.0 } else { 0 };
            out.extend_from_slice(&off.to_le_bytes());
            out.extend_from_slice(&s.field.1.to_le_bytes());
        }
        out.extend_from_slice(&self.fields);
        let tmp = path.with_extension("tape.partial");
        let mut f = File::create(&tmp)?;
        f.write_all(&out)?;
        drop(f);
        std::fs::rename(&tmp, path)
    }
}

/// `nx, ny` (u32), `cell, origin x, origin y` (f64), the kept box `i0, j0, w, h` (u32), then
/// `uz, ux, uy` of each kept cell (f32, row by row).
pub(super) fn encode_field(f: &SurfaceField, out: &mut Vec<u8>) {
    let (nx, ny) = (f.nx, f.ny);
    let (mut i0, mut i1, mut j0, mut j1) = (usize::MAX, 0, usize::MAX, 0);
    for j in 0..ny {
        for i in 0..nx {
            let k = j * nx + i;
            let big = [f.uz_mm[k], f.ux_mm[k], f.uy_mm[k]]
                .iter()
                .any(|v| v.abs() > CROP_MM);
            if big {
                (i0, i1, j0, j1) = (i0.min(i), i1.max(i), j0.min(j), j1.max(j));
            }
        }
    }
    let (w, h) = if i0 == usize::MAX {
        (i0, j0) = (0, 0);
        (0, 0)
    } else {
        (i1 + 1 - i0, j1 + 1 - j0)
    };
    for v in [nx, ny] {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
    for v in [f.cell_mm, f.origin_mm[0], f.origin_mm[1]] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in [i0, j0, w, h] {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
    for j in j0..j0 + h {
        for i in i0..i0 + w {
            let k = j * nx + i;
            for v in [f.uz_mm[k], f.ux_mm[k], f.uy_mm[k]] {
                out.extend_from_slice(&(v as f32).to_le_bytes());
            }
        }
    }
}

pub(super) fn decode_field(buf: &[u8]) -> io::Result<SurfaceField> {
    if buf.len() < 8 + 24 + 16 {
        return Err(bad("short field"));
    }
    let mut r = Reader(buf);
    let (nx, ny) = (r.u32() as usize, r.u32() as usize);
    let (cell_mm, ox, oy) = (r.f64(), r.f64(), r.f64());
    let (i0, j0, w, h) = (
        r.u32() as usize,
        r.u32() as usize,
        r.u32() as usize,
        r.u32() as usize,
    );
    if nx.checked_mul(ny).is_none_or(|n| n > 1 << 26)
        || i0 + w > nx
        || j0 + h > ny
        || r.0.len() != w * h * 12
    {
        return Err(bad("damaged field"));
    }
    let mut f = SurfaceField::unloaded(nx, ny, cell_mm, [ox, oy]);
    for j in j0..j0 + h {
        for i in i0..i0 + w {
            let k = j * nx + i;
            f.uz_mm[k] = r.f32() as f64;
            f.ux_mm[k] = r.f32() as f64;
            f.uy_mm[k] = r.f32() as f64;
        }
    }
    Ok(f)
}

pub(super) struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    pub(super) fn take<const N: usize>(&mut self) -> [u8; N] {
        let (a, b) = self.0.split_at(N);
        self.0 = b;
        a.try_into().expect("N bytes")
    }
    pub(super) fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    pub(super) fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    pub(super) fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
    pub(super) fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
}

pub(super) fn bad(msg: &str) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

/// `a + s (b − a)` of two fields on the same grid (`None`: the unloaded gel).
pub(super) fn blend(
    a: Option<&SurfaceField>,
    b: Option<&SurfaceField>,
    s: f64,
) -> Option<SurfaceField> {
    let (ka, kb) = (1.0 - s, s);
    let mix = |x: Option<&Vec<f64>>, y: Option<&Vec<f64>>, n: usize| -> Vec<f64> {
        (0..n)
            .map(|k| ka * x.map_or(0.0, |v| v[k]) + kb * y.map_or(0.0, |v| v[k]))
            .collect()
    };
    let g = a.or(b)?;
    if let (Some(a), Some(b)) = (a, b)
        && (a.nx, a.ny) != (b.nx, b.ny)
    {
        return Some(if s < 0.5 { a.clone() } else { b.clone() });
    }
    let n = g.nx * g.ny;
    // (Not `..SurfaceField::unloaded(..)`: that would allocate three grids to drop, on every
    // replayed step.)
    Some(SurfaceField {
        nx: g.nx,
        ny: g.ny,
        cell_mm: g.cell_mm,
        origin_mm: g.origin_mm,
        uz_mm: mix(a.map(|f| &f.uz_mm), b.map(|f| &f.uz_mm), n),
        ux_mm: mix(a.map(|f| &f.ux_mm), b.map(|f| &f.ux_mm), n),
        uy_mm: mix(a.map(|f| &f.uy_mm), b.map(|f| &f.uy_mm), n),
        pressure_mpa: vec![0.0; n],
        traction_x_mpa: vec![0.0; n],
        traction_y_mpa: vec![0.0; n],
    })
}
