//! Softmax over the last axis, one pass of plain code per row: what the
//! frame graphs' attention runs on tract in place of tract's own
//! `Softmax`.
//!
//! On x86-64, tract 0.23 runs a float softmax whose rows are short (the
//! local decoder's 43 keys, the global's 202) as three vector-kernel
//! calls per row (max, exp-sum, scale), each with its set-up; a batch-4
//! local step spent 18 % of its time in its two softmaxes, at about 1.3
//! µs a row (bench/RESULTS.md, "tract's operators one by one"). Here a row
//! is a max, an `exp` of each entry and a scale; the masked keys (the
//! caches' unfilled rows, biased by −1e9) cost an `exp` that underflows at
//! once.

use tract_onnx::tract_core::internal::*;
use tract_onnx::tract_core::ops::nn::{Softmax, SoftmaxKind};

/// `softmax(x)` over the last axis of an f32 tensor.
#[derive(Debug, Clone, Hash, PartialEq, Eq)]
pub(super) struct RowSoftmax;

impl Op for RowSoftmax {
    fn name(&self) -> StaticName {
        "RowSoftmax".into()
    }

    op_as_typed_op!();
}

impl EvalOp for RowSoftmax {
    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let mut t = args_1!(inputs).into_tensor();
        let n = *t.shape().last().context("softmax of a scalar")?;
        if n > 0 {
            let mut plain = t.try_as_plain_ram_mut()?;
            softmax_rows(plain.as_slice_mut::<f32>()?, n);
        }
        Ok(tvec!(t.into_tvalue()))
    }

    op_out_of_plan!();
}

impl TypedOp for RowSoftmax {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        ensure!(
            inputs[0].datum_type == f32::datum_type(),
            "RowSoftmax is f32 only"
        );
        Ok(tvec!(inputs[0].without_value()))
    }

    as_op!();
}

/// Each `n`-long row of `data` replaced by its softmax.
pub(super) fn softmax_rows(data: &mut [f32], n: usize) {
    for row in data.chunks_mut(n) {
        let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let mut sum = 0.0f32;
        for x in row.iter_mut() {
            *x = (*x - max).exp();
            sum += *x;
        }
        let r = sum.recip();
        for x in row.iter_mut() {
            *x *= r;
        }
    }
}

/// `model` with every f32 softmax over its last axis run as
/// [`RowSoftmax`]; other softmaxes are left as they are.
pub(super) fn rows_by_plain_code(mut model: TypedModel) -> TractResult<TypedModel> {
    let ids: Vec<usize> = model
        .nodes()
        .iter()
        .filter(|n| {
            n.op_as::<Softmax>().is_some_and(|s| {
                s.kind == SoftmaxKind::Softmax
                    && s.quant_output_dt.is_none()
                    && n.outputs[0].fact.datum_type == f32::datum_type()
                    && s.axes.len() == 1
                    && s.axes[0] + 1 == n.outputs[0].fact.rank()
            })
        })
        .map(|n| n.id)
        .collect();
    for id in ids {
        let node = model.node(id).clone();
        TypedModelPatch::replace_single_op(&model, &node, &node.inputs, RowSoftmax)?
            .apply(&mut model)?;
    }
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_sum_to_one_and_masked_keys_get_nothing() {
        let mut d = vec![1.0f32, 2.0, 3.0, -1e9, 0.5, 0.5, 0.5, 0.5];
        softmax_rows(&mut d, 4);
        let e: f64 = (1f64.exp() + 2f64.exp() + 3f64.exp()).recip();
        for (got, want) in d[..3]
            .iter()
            .zip([1f64.exp() * e, 2f64.exp() * e, 3f64.exp() * e])
        {
            assert!((*got as f64 - want).abs() < 1e-6, "{got} vs {want}");
        }
        assert_eq!(d[3], 0.0);
        assert!(d[4..].iter().all(|&x| (x - 0.25).abs() < 1e-7));
    }

    #[test]
    fn a_last_axis_softmax_is_replaced_and_answers_as_tracts() -> TractResult<()> {
        // Two softmaxes of one input: over the last axis (replaced) and
        // over the middle one (left to tract).
        let mut m = TypedModel::default();
        let x = m.add_source("x", f32::fact([2, 3, 43]))?;
        let last = Softmax::new(tvec![2], None, SoftmaxKind::Softmax);
        let mid = Softmax::new(tvec![1], None, SoftmaxKind::Softmax);
        let a = m.wire_node("last", last, &[x])?[0];
        let b = m.wire_node("mid", mid, &[x])?[0];
        m.select_output_outlets(&[a, b])?;
        let patched = rows_by_plain_code(m.clone())?;
        let names: Vec<String> = patched
            .nodes()
            .iter()
            .map(|n| n.op().name().to_string())
            .collect();
        assert_eq!(
            names.iter().filter(|n| *n == "RowSoftmax").count(),
            1,
            "{names:?}"
        );
        assert_eq!(
            names.iter().filter(|n| *n == "Softmax").count(),
            1,
            "{names:?}"
        );
        let input: Vec<f32> = (0..2 * 3 * 43)
            .map(|i| {
                if i % 7 == 3 {
                    -1e9
                } else {
                    ((i * 37) % 23) as f32 * 0.4 - 4.0
                }
            })
            .collect();
        let run = |m: TypedModel| -> TractResult<TVec<TValue>> {
            let t = Tensor::from_shape(&[2, 3, 43], &input)?;
            m.into_optimized()?
                .into_runnable()?
                .run(tvec![t.into_tvalue()])
        };
        let (want, got) = (run(m)?, run(patched)?);
        for (w, g) in want.iter().zip(&got) {
            let (w, g) = (w.try_as_plain_ram()?, g.try_as_plain_ram()?);
            let (w, g) = (w.as_slice::<f32>()?, g.as_slice::<f32>()?);
            for (a, b) in w.iter().zip(g) {
                assert!((a - b).abs() < 1e-6, "{a} vs {b}");
            }
        }
        Ok(())
    }
}
