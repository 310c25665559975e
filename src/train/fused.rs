//! One-pass CPU kernels, with one-pass gradients, for the trainer's
//! element-wise hot spots: LayerNorm, softmax over the last axis and GELU
//! (erf form). Composed from candle's primitives each of them costs 5–8
//! passes over its tensor forward and twice that backward, each pass a
//! fresh allocation; on the frame model's local decoder (50,400 slots a
//! batch) those passes, not the matrix products, were most of a step.
//! Same arithmetic as the composed forms but for GELU's erf, a vectorisable
//! rational form within 4.4e-7 of libm's (checked against the composed
//! forms, values and gradients, and the erf against libm, in this module's
//! tests); f32, CPU; any other input is an error naming the op.

use candle_core::{
    bail, CpuStorage, CustomOp1, CustomOp2, CustomOp3, Layout, Result, Shape, Tensor,
};

/// A contiguous f32 input's values.
fn values<'a>(op: &str, s: &'a CpuStorage, l: &Layout) -> Result<&'a [f32]> {
    match (s, l.contiguous_offsets()) {
        (CpuStorage::F32(v), Some((a, b))) => Ok(&v[a..b]),
        (CpuStorage::F32(_), None) => bail!("{op}: the input is not contiguous"),
        _ => bail!("{op}: f32 only"),
    }
}

/// Three inputs' values (see [`values`]).
fn values3<'a>(op: &str, inputs: [(&'a CpuStorage, &Layout); 3]) -> Result<[&'a [f32]; 3]> {
    let [(s1, l1), (s2, l2), (s3, l3)] = inputs;
    Ok([
        values(op, s1, l1)?,
        values(op, s2, l2)?,
        values(op, s3, l3)?,
    ])
}

/// The last axis's length of a layout (1 for a scalar).
fn last(l: &Layout) -> usize {
    l.dims().last().copied().unwrap_or(1).max(1)
}

/// Below this, `exp` underflows to a subnormal or zero, through libm's slow
/// path; the term is below f32's resolution of any softmax sum anyway.
const EXP_FLOOR: f32 = -87.0;

/// `exp(z)`, 0 below [`EXP_FLOOR`] (where libm would take its slow
/// underflow path, 3 % of a training step in GELU's gradient).
#[inline(always)]
fn floored_exp(z: f32) -> f32 {
    if z < EXP_FLOOR {
        0.0
    } else {
        z.exp()
    }
}

/// A one-pass kernel of one input, with its one-pass gradient.
enum Unary {
    /// Softmax over the last axis.
    Softmax,
    /// GELU, erf form: `x Φ(x) = ½ x (1 + erf(x/√2))`.
    Gelu,
}

const FRAC_1_SQRT_2: f32 = std::f32::consts::FRAC_1_SQRT_2;
/// 1/√(2π).
const INV_SQRT_2PI: f32 = 0.398_942_3;

use crate::lm::engine::kernels::erf;

/// Φ(x), the standard normal's distribution function.
fn cdf(v: f32) -> f32 {
    0.5 * (1.0 + erf(v * FRAC_1_SQRT_2))
}

impl CustomOp1 for Unary {
    fn name(&self) -> &'static str {
        match self {
            Unary::Softmax => "fused-softmax",
            Unary::Gelu => "fused-gelu-erf",
        }
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let x = values(self.name(), s, l)?;
        // Filled as it goes (no zeroing pass over a fresh buffer).
        let mut out = Vec::with_capacity(x.len());
        match self {
            Unary::Softmax => {
                for xr in x.chunks_exact(last(l)) {
                    let mx = xr.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                    let start = out.len();
                    out.extend(xr.iter().map(|&v| floored_exp(v - mx)));
                    let row = &mut out[start..];
                    let inv = 1.0 / row.iter().sum::<f32>();
                    row.iter_mut().for_each(|y| *y *= inv);
                }
            }
            // candle's order of operations, with the vectorised erf.
            Unary::Gelu => out.extend(x.iter().map(|&v| (erf(v * FRAC_1_SQRT_2) + 1.0) * 0.5 * v)),
        }
        Ok((CpuStorage::F32(out), l.shape().clone()))
    }

    fn bwd(&self, x: &Tensor, y: &Tensor, g: &Tensor) -> Result<Option<Tensor>> {
        match self {
            // `p (g − Σ g p)` per row, from the output p.
            Unary::Softmax => rows2(y, g, "fused-softmax-bwd", |pr, gr, out| {
                let dot: f32 = pr.iter().zip(gr).map(|(a, b)| a * b).sum();
                out.extend(pr.iter().zip(gr).map(|(&a, &b)| a * (b - dot)));
            }),
            // `g (Φ(x) + x φ(x))`, from the input.
            Unary::Gelu => {
                rows2(x, g, "fused-gelu-erf-bwd", |xr, gr, out| {
                    out.extend(xr.iter().zip(gr).map(|(&v, &gv)| {
                        gv * (cdf(v) + v * INV_SQRT_2PI * floored_exp(-0.5 * v * v))
                    }));
                })
            }
        }
    }
}

/// A one-pass kernel over two inputs of one shape, row by row along the
/// last axis: `row(a, b, out)` appends the row's output (the gradients'
/// form: the forward's input or output, and the output's gradient).
struct Rows2 {
    name: &'static str,
    row: fn(&[f32], &[f32], &mut Vec<f32>),
}

impl CustomOp2 for Rows2 {
    fn name(&self) -> &'static str {
        self.name
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (a, b) = (values(self.name, s1, l1)?, values(self.name, s2, l2)?);
        if l1.dims() != l2.dims() {
            bail!("{}: shapes {:?} and {:?}", self.name, l1.dims(), l2.dims());
        }
        let d = last(l1);
        let mut out = Vec::with_capacity(a.len());
        for (ar, br) in a.chunks_exact(d).zip(b.chunks_exact(d)) {
            (self.row)(ar, br, &mut out);
        }
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

/// [`Rows2`] on `a` and `g`, as a gradient.
fn rows2(
    a: &Tensor,
    g: &Tensor,
    name: &'static str,
    row: fn(&[f32], &[f32], &mut Vec<f32>),
) -> Result<Option<Tensor>> {
    let op = Rows2 { name, row };
    Ok(Some(
        a.contiguous()?.apply_op2_no_bwd(&g.contiguous()?, &op)?,
    ))
}

/// LayerNorm over the last axis, `(x − mean) / √(var + eps) · w + b`; with
/// `grad`, its gradients instead (inputs `x`, `w` and the output's
/// gradient `g`, `[rows, d]`; output `[rows + 2, d]`: the input's
/// gradient, then the weight's and the bias's, summed over the rows).
struct LayerNorm {
    eps: f32,
    grad: bool,
}

impl LayerNorm {
    /// A row's mean and 1/√(var + eps).
    fn stats(&self, r: &[f32]) -> (f32, f32) {
        let d = r.len() as f32;
        let mean = r.iter().sum::<f32>() / d;
        let var = r.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / d;
        (mean, 1.0 / (var + self.eps).sqrt())
    }

    fn forward(&self, x: &[f32], w: &[f32], b: &[f32], d: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(x.len());
        for xr in x.chunks_exact(d) {
            let (mean, rstd) = self.stats(xr);
            out.extend((0..d).map(|j| (xr[j] - mean) * rstd * w[j] + b[j]));
        }
        out
    }

    fn backward(&self, x: &[f32], w: &[f32], g: &[f32], d: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(x.len() + 2 * d);
        let (mut dw, mut db) = (vec![0f32; d], vec![0f32; d]);
        let mut xhat = vec![0f32; d];
        let mut gw = vec![0f32; d];
        for (xr, gr) in x.chunks_exact(d).zip(g.chunks_exact(d)) {
            let (mean, rstd) = self.stats(xr);
            let (mut m_gw, mut m_gwx) = (0f32, 0f32);
            for j in 0..d {
                xhat[j] = (xr[j] - mean) * rstd;
                gw[j] = gr[j] * w[j];
                m_gw += gw[j];
                m_gwx += gw[j] * xhat[j];
                dw[j] += gr[j] * xhat[j];
                db[j] += gr[j];
            }
            let (m_gw, m_gwx) = (m_gw / d as f32, m_gwx / d as f32);
            out.extend((0..d).map(|j| rstd * (gw[j] - m_gw - xhat[j] * m_gwx)));
        }
        out.extend(dw);
        out.extend(db);
        out
    }
}

impl CustomOp3 for LayerNorm {
    fn name(&self) -> &'static str {
        if self.grad {
            "fused-layer-norm-bwd"
        } else {
            "fused-layer-norm"
        }
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let [x, w, b_or_g] = values3(self.name(), [(s1, l1), (s2, l2), (s3, l3)])?;
        let d = last(l1);
        if self.grad {
            let rows = x.len() / d;
            let out = self.backward(x, w, b_or_g, d);
            return Ok((CpuStorage::F32(out), Shape::from((rows + 2, d))));
        }
        if w.len() != d || b_or_g.len() != d {
            bail!(
                "{}: weights of {} and {} for rows of {d}",
                self.name(),
                w.len(),
                b_or_g.len()
            );
        }
        let out = self.forward(x, w, b_or_g, d);
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _b: &Tensor,
        _y: &Tensor,
        g: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        // One pass writes the input's gradient and, in two extra rows, the
        // weight's and the bias's.
        let d = x.dim(candle_core::D::Minus1)?;
        let rows = x.elem_count() / d.max(1);
        let grad = LayerNorm {
            eps: self.eps,
            grad: true,
        };
        let all = x.contiguous()?.reshape((rows, d))?.apply_op3_no_bwd(
            &w.contiguous()?,
            &g.contiguous()?.reshape((rows, d))?,
            &grad,
        )?;
        let dx = all.narrow(0, 0, rows)?.reshape(x.shape())?;
        let dw = all.narrow(0, rows, 1)?.reshape(d)?;
        let db = all.narrow(0, rows + 1, 1)?.reshape(d)?;
        Ok((Some(dx), Some(dw), Some(db)))
    }
}

/// Softmax over the last axis (its gradient in one pass too).
pub fn softmax_last_dim(x: &Tensor) -> Result<Tensor> {
    x.contiguous()?.apply_op1(Unary::Softmax)
}

/// LayerNorm over the last axis with weight `w` and bias `b` (`[d]`).
pub fn layer_norm(x: &Tensor, w: &Tensor, b: &Tensor, eps: f64) -> Result<Tensor> {
    x.contiguous()?.apply_op3(
        &w.contiguous()?,
        &b.contiguous()?,
        LayerNorm {
            eps: eps as f32,
            grad: false,
        },
    )
}

/// GELU in its erf form.
pub fn gelu_erf(x: &Tensor) -> Result<Tensor> {
    x.contiguous()?.apply_op1(Unary::Gelu)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var, D};

    /// The composed forms the fused ones replace.
    fn softmax_ref(x: &Tensor) -> Result<Tensor> {
        let mx = x.max_keepdim(D::Minus1)?;
        let e = x.broadcast_sub(&mx)?.exp()?;
        e.broadcast_div(&e.sum_keepdim(D::Minus1)?)
    }
    fn layer_norm_ref(x: &Tensor, w: &Tensor, b: &Tensor, eps: f64) -> Result<Tensor> {
        let d = x.dim(D::Minus1)? as f64;
        let xc = x.broadcast_sub(&(x.sum_keepdim(D::Minus1)? / d)?)?;
        let var = (xc.sqr()?.sum_keepdim(D::Minus1)? / d)?;
        xc.broadcast_div(&(var + eps)?.sqrt()?)?
            .broadcast_mul(w)?
            .broadcast_add(b)
    }

    fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
        (a - b)
            .unwrap()
            .abs()
            .unwrap()
            .flatten_all()
            .unwrap()
            .max(0)
            .unwrap()
            .to_scalar::<f32>()
            .unwrap()
    }

    /// Values and gradients (through a random weighting of the output, so
    /// every output element's gradient differs) of `fused` and `composed`
    /// on the same inputs.
    fn check(
        name: &str,
        inputs: &[Var],
        fused: &dyn Fn(&[Tensor]) -> Result<Tensor>,
        composed: &dyn Fn(&[Tensor]) -> Result<Tensor>,
        tol: f32,
    ) {
        let ts: Vec<Tensor> = inputs.iter().map(|v| v.as_tensor().clone()).collect();
        let (yf, yc) = (fused(&ts).unwrap(), composed(&ts).unwrap());
        assert!(
            max_diff(&yf, &yc) < tol,
            "{name}: values differ by {}",
            max_diff(&yf, &yc)
        );
        let r = Tensor::randn(0f32, 1.0, yf.shape(), yf.device()).unwrap();
        let gf = (yf * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let gc = (yc * &r).unwrap().sum_all().unwrap().backward().unwrap();
        for (i, v) in inputs.iter().enumerate() {
            let (a, b) = (
                gf.get(v.as_tensor()).unwrap(),
                gc.get(v.as_tensor()).unwrap(),
            );
            let scale = b.abs().unwrap().flatten_all().unwrap().max(0).unwrap();
            let scale = scale.to_scalar::<f32>().unwrap().max(1.0);
            let diff = max_diff(a, b);
            assert!(
                diff < tol * scale,
                "{name}: input {i}'s gradient differs by {diff}"
            );
        }
    }

    #[test]
    fn fused_ops_match_the_composed_ones_in_values_and_gradients() {
        let dev = Device::Cpu;
        let var = |shape: &[usize], std: f32, mean: f32| {
            Var::from_tensor(
                &(Tensor::randn(0f32, std, shape, &dev).unwrap() + mean as f64).unwrap(),
            )
            .unwrap()
        };
        // Softmax rows with a causal mask's −1e9 (the floor's path) and
        // large logits.
        let x = var(&[3, 4, 7, 7], 4.0, 0.0);
        let mask = Tensor::from_vec(
            (0..49)
                .map(|i| if i % 7 > i / 7 { -1e9f32 } else { 0.0 })
                .collect::<Vec<_>>(),
            (1, 1, 7, 7),
            &dev,
        )
        .unwrap();
        check(
            "softmax",
            &[x],
            &|t| softmax_last_dim(&t[0].broadcast_add(&mask)?),
            &|t| softmax_ref(&t[0].broadcast_add(&mask)?),
            1e-6,
        );
        // LayerNorm on rows far from zero mean, with real weights.
        let (x, w, b) = (
            var(&[5, 6, 48], 3.0, 2.0),
            var(&[48], 0.5, 1.0),
            var(&[48], 0.3, 0.0),
        );
        check(
            "layer_norm",
            &[x, w, b],
            &|t| layer_norm(&t[0], &t[1], &t[2], 1e-5),
            &|t| layer_norm_ref(&t[0], &t[1], &t[2], 1e-5),
            1e-5,
        );
        // GELU: ½ x times the erf's bound (4.4e-7) where erf has not
        // saturated (|x| < 5.5) is at most 1.2e-6.
        let x = var(&[4, 257], 2.5, 0.0);
        check(
            "gelu",
            &[x],
            &|t| gelu_erf(&t[0]),
            &|t| t[0].gelu_erf(),
            2e-6,
        );
    }

    #[test]
    fn the_vectorised_erf_stays_within_its_bound_of_libm() {
        let mut worst = (0.0f64, 0.0f32);
        for i in 0..=1_000_000 {
            let x = -6.0 + 12.0 * i as f32 / 1e6;
            let e = (erf(x) as f64 - candle_core::cpu::erf::erf_f64(x as f64)).abs();
            if e > worst.0 {
                worst = (e, x);
            }
        }
        assert!(worst.0 < 4.5e-7, "erf off by {:e} at {}", worst.0, worst.1);
        assert_eq!(erf(0.0), 0.0);
        assert_eq!(erf(10.0), 1.0);
        assert_eq!(erf(-10.0), -1.0);
        assert!(erf(f32::NAN).is_nan());
    }

    #[test]
    fn fused_ops_refuse_what_they_do_not_compute() {
        let dev = Device::Cpu;
        let x = Tensor::zeros((2, 3), candle_core::DType::F64, &dev).unwrap();
        let e = softmax_last_dim(&x).unwrap_err().to_string();
        assert!(e.contains("fused-softmax") && e.contains("f32"), "{e}");
        let x = Tensor::zeros((2, 3), candle_core::DType::F32, &dev).unwrap();
        let w = Tensor::ones(4, candle_core::DType::F32, &dev).unwrap();
        let e = layer_norm(&x, &w, &w, 1e-5).unwrap_err().to_string();
        assert!(
            e.contains("fused-layer-norm") && e.contains("rows of 3"),
            "{e}"
        );
    }
}
