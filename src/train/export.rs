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
use tract_onnx::pb::{
    attribute_proto::AttributeType, tensor_proto::DataType, tensor_shape_proto::dimension,
    tensor_shape_proto::Dimension, type_proto, AttributeProto, GraphProto, ModelProto, NodeProto,
    OperatorSetIdProto, TensorProto, TensorShapeProto, TypeProto, ValueInfoProto,
};

pub const ONNX_FILE: &str = "model.onnx";

#[derive(Default)]
struct Builder {
    nodes: Vec<NodeProto>,
    inits: Vec<TensorProto>,
    count: usize,
}

fn attr_i(name: &str, i: i64) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Int as i32,
        i,
        ..Default::default()
    }
}
fn attr_f(name: &str, f: f32) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Float as i32,
        f,
        ..Default::default()
    }
}
fn attr_ints(name: &str, ints: &[i64]) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Ints as i32,
        ints: ints.to_vec(),
        ..Default::default()
    }
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
    fn op(
        &mut self,
        op: &str,
        inputs: &[&str],
        attrs: Vec<AttributeProto>,
        out: Option<&str>,
    ) -> String {
        self.count += 1;
        let o = out
            .map(str::to_string)
            .unwrap_or_else(|| format!("{}_{}", op.to_lowercase(), self.count));
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![o.clone()],
            name: format!("n{}_{op}", self.count),
            op_type: op.into(),
            attribute: attrs,
            ..Default::default()
        });
        o
    }
    fn f32(&mut self, name: &str, dims: &[usize], data: Vec<f32>) -> String {
        self.inits.push(TensorProto {
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: DataType::Float as i32,
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            name: name.into(),
            ..Default::default()
        });
        name.into()
    }
    fn i64(&mut self, name: &str, data: &[i64]) -> String {
        self.inits.push(TensorProto {
            dims: vec![data.len() as i64],
            data_type: DataType::Int64 as i32,
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            name: name.into(),
            ..Default::default()
        });
        name.into()
    }
    fn scalar(&mut self, name: &str, v: f32) -> String {
        self.f32(name, &[], vec![v])
    }
}

fn weights(model: &Gpt) -> anyhow::Result<BTreeMap<String, (Vec<usize>, Vec<f32>)>> {
    let mut out = BTreeMap::new();
    for (k, t) in model.tensors() {
        let dims = t.dims().to_vec();
        let data = t.flatten_all()?.to_vec1::<f32>()?;
        out.insert(k, (dims, data));
    }
    Ok(out)
}

/// The model's graph as an ONNX `ModelProto`.
pub fn onnx_model(model: &Gpt) -> anyhow::Result<ModelProto> {
    let cfg = &model.cfg;
    let w = weights(model)?;
    let mut g = Builder::default();
    for (name, (dims, data)) in w {
        g.f32(&name, &dims, data);
    }
    let (d, h, dh) = (cfg.d_model as i64, cfg.n_heads as i64, cfg.d_head() as i64);
    let shape_heads = g.i64("shape_heads", &[0, 0, h, dh]);
    let shape_model = g.i64("shape_model", &[0, 0, d]);
    let scale = g.scalar("attn_scale", 1.0 / (dh as f32).sqrt());
    let half = g.scalar("half", 0.5);
    let one = g.scalar("one", 1.0);
    let inv_sqrt2 = g.scalar("inv_sqrt2", std::f32::consts::FRAC_1_SQRT_2);
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
    let ln = |g: &mut Builder, x: &str, pre: &str| {
        g.op(
            "LayerNormalization",
            &[x, &format!("{pre}.w"), &format!("{pre}.b")],
            vec![attr_i("axis", -1), attr_f("epsilon", eps)],
            None,
        )
    };
    let lin = |g: &mut Builder, x: &str, pre: &str| {
        let m = g.op("MatMul", &[x, &format!("{pre}.w")], vec![], None);
        g.op("Add", &[&m, &format!("{pre}.b")], vec![], None)
    };
    for l in 0..cfg.n_layers {
        let n = |s: &str| format!("h{l}.{s}");
        let a = ln(&mut g, &x, &n("ln1"));
        let heads = |g: &mut Builder, which: &str| {
            let y = lin(g, &a, &n(which));
            let y = g.op("Reshape", &[&y, &shape_heads], vec![], None);
            g.op(
                "Transpose",
                &[&y],
                vec![attr_ints("perm", &[0, 2, 1, 3])],
                None,
            )
        };
        let q = heads(&mut g, "q");
        let k = heads(&mut g, "k");
        let v = heads(&mut g, "v");
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
        let kt = g.op(
            "Transpose",
            &[&pk],
            vec![attr_ints("perm", &[0, 1, 3, 2])],
            None,
        );
        let s = g.op("MatMul", &[&q, &kt], vec![], None);
        let s = g.op("Mul", &[&s, &scale], vec![], None);
        let s = g.op("Add", &[&s, "attn_bias"], vec![], None);
        let p = g.op("Softmax", &[&s], vec![attr_i("axis", -1)], None);
        let att = g.op("MatMul", &[&p, &pv], vec![], None);
        let att = g.op(
            "Transpose",
            &[&att],
            vec![attr_ints("perm", &[0, 2, 1, 3])],
            None,
        );
        let att = g.op("Reshape", &[&att, &shape_model], vec![], None);
        let o = lin(&mut g, &att, &n("o"));
        x = g.op("Add", &[&x, &o], vec![], None);
        let m = ln(&mut g, &x, &n("ln2"));
        let f = lin(&mut g, &m, &n("fc1"));
        let e = g.op("Mul", &[&f, &inv_sqrt2], vec![], None);
        let e = g.op("Erf", &[&e], vec![], None);
        let e = g.op("Add", &[&e, &one], vec![], None);
        let hf = g.op("Mul", &[&f, &half], vec![], None);
        let gl = g.op("Mul", &[&hf, &e], vec![], None);
        let f2 = lin(&mut g, &gl, &n("fc2"));
        x = g.op("Add", &[&x, &f2], vec![], None);
    }
    let xf = ln(&mut g, &x, "ln_f");
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
    Ok(ModelProto {
        ir_version: 8,
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: 17,
        }],
        producer_name: "choreo-train".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        graph: Some(GraphProto {
            node: g.nodes,
            name: "choreo_motion_lm".into(),
            initializer: g.inits,
            input: inputs,
            output: outputs,
            ..Default::default()
        }),
        ..Default::default()
    })
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
