//! ONNX export written directly from Rust with the prost types tract
//! ships (`tract_onnx::pb`): the same operations as `model.rs`, one node
//! each, with past keys/values as inputs and the extended ones as outputs
//! (incremental decoding). Opset 17 (LayerNormalization), IR version 8.

use super::model::Gpt;
use crate::lm::manifest::{sha256_hex, DataInfo, MANIFEST_FORMAT};
use crate::lm::runtime::{input_names, output_names};
use crate::lm::{Manifest, PosScheme};
use crate::tokenize::vocab::Vocabulary;
use prost::Message;
use std::collections::BTreeMap;
use std::path::Path;
pub(crate) use tract_onnx::pb::tensor_proto::DataType;
use tract_onnx::pb::{
    attribute_proto::AttributeType, tensor_shape_proto::dimension, tensor_shape_proto::Dimension,
    type_proto, AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, TensorProto,
    TensorShapeProto, TypeProto, ValueInfoProto,
};

pub const ONNX_FILE: &str = "model.onnx";

/// Collects nodes and initialisers of one graph.
#[derive(Default)]
pub(crate) struct Builder {
    pub(crate) nodes: Vec<NodeProto>,
    pub(crate) inits: Vec<TensorProto>,
    count: usize,
}

pub(crate) fn attr_i(name: &str, i: i64) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Int as i32,
        i,
        ..Default::default()
    }
}
pub(crate) fn attr_f(name: &str, f: f32) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Float as i32,
        f,
        ..Default::default()
    }
}
pub(crate) fn attr_ints(name: &str, ints: &[i64]) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Ints as i32,
        ints: ints.to_vec(),
        ..Default::default()
    }
}

/// The float initialisers of an ONNX file as tensors, by name (scalars
/// and shape constants included; callers pick their parameters by name).
pub fn float_initializers(
    path: &Path,
    dev: &candle_core::Device,
) -> anyhow::Result<BTreeMap<String, candle_core::Tensor>> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    let proto = ModelProto::decode(bytes.as_slice())
        .map_err(|e| anyhow::anyhow!("{file}: not an ONNX model: {e}"))?;
    let graph = proto
        .graph
        .ok_or_else(|| anyhow::anyhow!("{file}: no graph"))?;
    let mut t = BTreeMap::new();
    for init in &graph.initializer {
        let dims: Vec<usize> = init.dims.iter().map(|&d| d as usize).collect();
        if init.data_type != DataType::Float as i32
            || init.raw_data.len() != 4 * dims.iter().product::<usize>()
        {
            continue;
        }
        let data: Vec<f32> = init
            .raw_data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        t.insert(
            init.name.clone(),
            candle_core::Tensor::from_vec(data, dims, dev)?,
        );
    }
    Ok(t)
}

/// A tensor's type with named symbolic dimensions (`"B"`) or fixed ones.
pub fn value_info(name: &str, elem: DataType, dims: &[&str]) -> ValueInfoProto {
    let dim = dims
        .iter()
        .map(|d| Dimension {
            value: Some(match d.parse::<i64>() {
                Ok(n) => dimension::Value::DimValue(n),
                Err(_) => dimension::Value::DimParam(d.to_string()),
            }),
            ..Default::default()
        })
        .collect();
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: elem as i32,
                shape: Some(TensorShapeProto { dim }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

impl Builder {
    /// Adds a node; returns its output's name (`out` or a fresh one).
    pub(crate) fn op(
        &mut self,
        op: &str,
        inputs: &[&str],
        attrs: Vec<AttributeProto>,
        out: Option<&str>,
    ) -> String {
        let o = out
            .map(str::to_string)
            .unwrap_or_else(|| format!("{}_{}", op.to_lowercase(), self.count + 1));
        self.ops(op, inputs, attrs, &[&o]);
        o
    }
    /// Adds a node with several outputs, named `outs`.
    pub(crate) fn ops(
        &mut self,
        op: &str,
        inputs: &[&str],
        attrs: Vec<AttributeProto>,
        outs: &[&str],
    ) {
        self.count += 1;
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: outs.iter().map(|s| s.to_string()).collect(),
            name: format!("n{}_{op}", self.count),
            op_type: op.into(),
            attribute: attrs,
            ..Default::default()
        });
    }
    pub(crate) fn f32(&mut self, name: &str, dims: &[usize], data: Vec<f32>) -> String {
        self.inits.push(TensorProto {
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: DataType::Float as i32,
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            name: name.into(),
            ..Default::default()
        });
        name.into()
    }
    /// A constant int64 vector, added once per name (later calls reuse it).
    pub(crate) fn i64(&mut self, name: &str, data: &[i64]) -> String {
        if self.inits.iter().any(|t| t.name == name) {
            return name.into();
        }
        self.inits.push(TensorProto {
            dims: vec![data.len() as i64],
            data_type: DataType::Int64 as i32,
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            name: name.into(),
            ..Default::default()
        });
        name.into()
    }
    /// A constant f32 scalar, added once per name (later calls reuse it).
    pub(crate) fn scalar(&mut self, name: &str, v: f32) -> String {
        if self.inits.iter().any(|t| t.name == name) {
            return name.into();
        }
        self.f32(name, &[], vec![v])
    }

    /// Every named tensor as an initialiser.
    pub(crate) fn weights(
        &mut self,
        t: BTreeMap<String, candle_core::Tensor>,
    ) -> anyhow::Result<()> {
        for (name, t) in t {
            let dims = t.dims().to_vec();
            let data = t.flatten_all()?.to_vec1::<f32>()?;
            self.f32(&name, &dims, data);
        }
        Ok(())
    }

    /// `LayerNormalization` with `pre.w`, `pre.b`.
    pub(crate) fn ln(&mut self, x: &str, pre: &str, eps: f32) -> String {
        self.op(
            "LayerNormalization",
            &[x, &format!("{pre}.w"), &format!("{pre}.b")],
            vec![attr_i("axis", -1), attr_f("epsilon", eps)],
            None,
        )
    }

    /// `x · pre.w + pre.b`.
    pub(crate) fn lin(&mut self, x: &str, pre: &str) -> String {
        let m = self.op("MatMul", &[x, &format!("{pre}.w")], vec![], None);
        self.op("Add", &[&m, &format!("{pre}.b")], vec![], None)
    }

    /// `x · pre.w + pre.b` as one `Gemm` (`x` a matrix: one row each).
    pub(crate) fn gemm(&mut self, x: &str, pre: &str) -> String {
        self.op(
            "Gemm",
            &[x, &format!("{pre}.w"), &format!("{pre}.b")],
            vec![],
            None,
        )
    }

    /// GELU, erf form: (x · (1 + erf(x / √2))) · 0.5, written in the
    /// order onnxruntime's GELU fusion recognises (it then runs one
    /// operation where this writes five).
    pub(crate) fn gelu(&mut self, x: &str) -> String {
        let half = self.scalar("half", 0.5);
        let one = self.scalar("one", 1.0);
        let sqrt2 = self.scalar("sqrt2", std::f32::consts::SQRT_2);
        let e = self.op("Div", &[x, &sqrt2], vec![], None);
        let e = self.op("Erf", &[&e], vec![], None);
        let e = self.op("Add", &[&e, &one], vec![], None);
        let e = self.op("Mul", &[x, &e], vec![], None);
        self.op("Mul", &[&e, &half], vec![], None)
    }

    /// Queries, keys and values of a pre-LN block, `[B, H, T, dh]` each.
    pub(crate) fn qkv(
        &mut self,
        x: &str,
        pre: &dyn Fn(&str) -> String,
        eps: f32,
        h: i64,
        dh: i64,
    ) -> (String, String, String) {
        let a = self.ln(x, &pre("ln1"), eps);
        let [q, k, v] = ["q", "k", "v"].map(|w| {
            let y = self.lin(&a, &pre(w));
            self.heads(&y, h, dh)
        });
        (q, k, v)
    }

    /// `[B, T, d]` → `[B, H, T, dh]`.
    pub(crate) fn heads(&mut self, y: &str, h: i64, dh: i64) -> String {
        let shape = self.i64("shape_heads", &[0, 0, h, dh]);
        let y = self.op("Reshape", &[y, &shape], vec![], None);
        self.op(
            "Transpose",
            &[&y],
            vec![attr_ints("perm", &[0, 2, 1, 3])],
            None,
        )
    }

    /// Multi-head attention of `q` over `k`, `v` (all `[B, H, ·, dh]`),
    /// plus an additive bias; back to `[B, T, d]`.
    pub(crate) fn attend(
        &mut self,
        q: &str,
        k: &str,
        v: &str,
        bias: Option<&str>,
        d: i64,
        dh: i64,
    ) -> String {
        let scale = self.scalar("attn_scale", 1.0 / (dh as f32).sqrt());
        let shape_model = self.i64("shape_model", &[0, 0, d]);
        let kt = self.op(
            "Transpose",
            &[k],
            vec![attr_ints("perm", &[0, 1, 3, 2])],
            None,
        );
        let s = self.op("MatMul", &[q, &kt], vec![], None);
        let mut s = self.op("Mul", &[&s, &scale], vec![], None);
        if let Some(b) = bias {
            s = self.op("Add", &[&s, b], vec![], None);
        }
        let p = self.op("Softmax", &[&s], vec![attr_i("axis", -1)], None);
        let att = self.op("MatMul", &[&p, v], vec![], None);
        let att = self.op(
            "Transpose",
            &[&att],
            vec![attr_ints("perm", &[0, 2, 1, 3])],
            None,
        );
        self.op("Reshape", &[&att, &shape_model], vec![], None)
    }

    /// The MLP half of a pre-LN block: `x + fc2(gelu(fc1(ln2(x))))`.
    pub(crate) fn mlp_residual(
        &mut self,
        x: &str,
        pre: &dyn Fn(&str) -> String,
        eps: f32,
    ) -> String {
        let m = self.ln(x, &pre("ln2"), eps);
        let f = self.lin(&m, &pre("fc1"));
        let gl = self.gelu(&f);
        let f2 = self.lin(&gl, &pre("fc2"));
        self.op("Add", &[x, &f2], vec![], None)
    }

    /// The graph as an opset-17 model.
    pub(crate) fn model(
        self,
        name: &str,
        input: Vec<ValueInfoProto>,
        output: Vec<ValueInfoProto>,
    ) -> ModelProto {
        ModelProto {
            ir_version: 8,
            opset_import: vec![OperatorSetIdProto {
                domain: String::new(),
                version: 17,
            }],
            producer_name: "choreo-train".into(),
            producer_version: env!("CARGO_PKG_VERSION").into(),
            graph: Some(GraphProto {
                node: self.nodes,
                name: name.into(),
                initializer: self.inits,
                input,
                output,
                ..Default::default()
            }),
            ..Default::default()
        }
    }
}

/// The model's graph as an ONNX `ModelProto`.
pub fn onnx_model(model: &Gpt) -> anyhow::Result<ModelProto> {
    let cfg = &model.cfg;
    let mut g = Builder::default();
    g.weights(model.params.tensors())?;
    let (d, h, dh) = (cfg.d_model as i64, cfg.n_heads as i64, cfg.d_head() as i64);
    let eps = cfg.ln_eps as f32;

    let tok = g.op(
        "Gather",
        &["tok_emb", "tokens"],
        vec![attr_i("axis", 0)],
        None,
    );
    let pa = g.op(
        "Gather",
        &["pos_a", "pos_a_ids"],
        vec![attr_i("axis", 0)],
        None,
    );
    let mut x = g.op("Add", &[&tok, &pa], vec![], None);
    if cfg.positions == PosScheme::FrameSlot {
        let pb = g.op(
            "Gather",
            &["pos_b", "pos_b_ids"],
            vec![attr_i("axis", 0)],
            None,
        );
        x = g.op("Add", &[&x, &pb], vec![], None);
    }
    for l in 0..cfg.n_layers {
        let n = |s: &str| format!("h{l}.{s}");
        let (q, k, v) = g.qkv(&x, &n, eps, h, dh);
        let pk = format!("present_k_{l}");
        let pv = format!("present_v_{l}");
        g.op(
            "Concat",
            &[&format!("past_k_{l}"), &k],
            vec![attr_i("axis", 2)],
            Some(&pk),
        );
        g.op(
            "Concat",
            &[&format!("past_v_{l}"), &v],
            vec![attr_i("axis", 2)],
            Some(&pv),
        );
        let att = g.attend(&q, &pk, &pv, Some("attn_bias"), d, dh);
        let o = g.lin(&att, &n("o"));
        x = g.op("Add", &[&x, &o], vec![], None);
        x = g.mlp_residual(&x, &n, eps);
    }
    let xf = g.ln(&x, "ln_f", eps);
    let m = g.op("MatMul", &[&xf, "head.w"], vec![], None);
    g.op("Add", &[&m, "head.b"], vec![], Some("logits"));
    for (k, _) in &cfg.classes {
        let m = g.op("MatMul", &[&xf, &format!("cls.{k}.w")], vec![], None);
        g.op(
            "Add",
            &[&m, &format!("cls.{k}.b")],
            vec![],
            Some(&format!("cls_{k}")),
        );
    }

    // Graph inputs are the runtime's names (`pos_a_ids` index the table
    // `pos_a`).
    let mut inputs = Vec::new();
    for name in input_names(cfg) {
        let vi = match name.as_str() {
            "tokens" => value_info("tokens", DataType::Int64, &["B", "T"]),
            "pos_a_ids" | "pos_b_ids" => value_info(&name, DataType::Int64, &["B", "T"]),
            "attn_bias" => value_info("attn_bias", DataType::Float, &["T", "S"]),
            other => value_info(
                other,
                DataType::Float,
                &["B", &h.to_string(), "P", &dh.to_string()],
            ),
        };
        inputs.push(vi);
    }
    let mut outputs = Vec::new();
    for name in output_names(cfg) {
        let vi = if name == "logits" {
            value_info(
                "logits",
                DataType::Float,
                &["B", "T", &cfg.vocab_size.to_string()],
            )
        } else if let Some(k) = name.strip_prefix("cls_") {
            let c = cfg
                .classes
                .iter()
                .find(|(kk, _)| kk == k)
                .map(|c| c.1.len())
                .unwrap_or(0);
            value_info(&name, DataType::Float, &["B", "T", &c.to_string()])
        } else {
            value_info(
                &name,
                DataType::Float,
                &["B", &h.to_string(), "S", &dh.to_string()],
            )
        };
        outputs.push(vi);
    }
    Ok(g.model("choreo_motion_lm", inputs, outputs))
}

/// Writes `dir/model.onnx` and `dir/manifest.json`; returns the manifest.
pub fn export(
    model: &Gpt,
    vocabulary: &Vocabulary,
    data: DataInfo,
    metrics: BTreeMap<String, f64>,
    training: serde_json::Value,
    dir: &Path,
) -> anyhow::Result<Manifest> {
    std::fs::create_dir_all(dir)?;
    let bytes = onnx_model(model)?.encode_to_vec();
    let onnx_path = dir.join(ONNX_FILE);
    std::fs::write(&onnx_path, &bytes)?;
    let manifest = Manifest {
        format: MANIFEST_FORMAT,
        kind: "motion-lm".into(),
        config: model.cfg.clone(),
        vocabulary: vocabulary.clone(),
        onnx: ONNX_FILE.into(),
        onnx_sha256: sha256_hex(&bytes),
        data,
        inputs: input_names(&model.cfg),
        outputs: output_names(&model.cfg),
        metrics,
        training,
    };
    manifest.save(dir)?;
    Ok(manifest)
}
