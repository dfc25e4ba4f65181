//! The acting policy as an ONNX model (opset 13, IR 8), built from ONNX's own protobuf
//! messages ([`ess_proto::onnx`]).
//!
//! Inputs (float32, dynamic batch `N`):
//!
//! | name  | shape          | meaning |
//! |-------|----------------|---------|
//! | `obs` | `[N, obs_dim]` | raw observations, as the env writes them (the model normalises) |
//! | `eps` | `[N, 1]`       | the continuous latent in `[-1, 1]` (0 for methods without it) |
//! | `c`   | `[N, n_codes]` | the behaviour code, one-hot (code `k` imitates the mode matched to `k`) |
//!
//! Output `action` `[N, act_dim]`: the deterministic action `tanh(mean)`, in `[-1, 1]`
//! (the env maps it onto the actuators' ranges). The graph is
//! `x = concat((obs - obs_mean) / obs_std, eps, c)`, then per layer `Gemm` (weights
//! `[out, in]`, `transB = 1`) with `Tanh` between layers and on the output.

use ess_actor::PolicyWeights;
use ess_proto::onnx::{
    AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, StringStringEntryProto,
    TensorProto, TensorShapeProto, TypeProto, ValueInfoProto, attribute_proto, tensor_proto,
    tensor_shape_proto, type_proto,
};

/// ONNX IR version written (ONNX 1.10+ reads it).
pub const IR_VERSION: i64 = 8;
/// Default-domain opset written.
pub const OPSET: i64 = 13;

fn float_input(name: &str, width: usize) -> ValueInfoProto {
    let dim = |v: tensor_shape_proto::dimension::Value| tensor_shape_proto::Dimension {
        value: Some(v),
        ..Default::default()
    };
    ValueInfoProto {
        name: Some(name.into()),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: Some(tensor_proto::DataType::Float as i32),
                shape: Some(TensorShapeProto {
                    dim: vec![
                        dim(tensor_shape_proto::dimension::Value::DimParam("N".into())),
                        dim(tensor_shape_proto::dimension::Value::DimValue(width as i64)),
                    ],
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

fn initializer(name: &str, dims: &[usize], data: &[f32]) -> TensorProto {
    TensorProto {
        name: Some(name.into()),
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: Some(tensor_proto::DataType::Float as i32),
        float_data: data.to_vec(),
        ..Default::default()
    }
}

fn node(op: &str, inputs: &[&str], output: &str, attrs: Vec<AttributeProto>) -> NodeProto {
    NodeProto {
        op_type: Some(op.into()),
        name: Some(output.into()),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        attribute: attrs,
        ..Default::default()
    }
}

fn int_attr(name: &str, v: i64) -> AttributeProto {
    AttributeProto {
        name: Some(name.into()),
        r#type: Some(attribute_proto::AttributeType::Int as i32),
        i: Some(v),
        ..Default::default()
    }
}

/// The model of `w`; `meta` goes into the model's `metadata_props`.
pub fn policy_model(w: &PolicyWeights, meta: &[(String, String)]) -> ModelProto {
    let layout = w.mean.layout();
    let sizes = &layout.sizes;
    let (od, ad) = (w.obs_mean.len(), layout.output());
    let n_codes = sizes[0] - od - 1;
    let mut inits = vec![
        initializer("obs_mean", &[od], &w.obs_mean),
        initializer("obs_std", &[od], &w.obs_std),
    ];
    let mut nodes = vec![
        node("Sub", &["obs", "obs_mean"], "obs_centred", vec![]),
        node("Div", &["obs_centred", "obs_std"], "obs_norm", vec![]),
        node(
            "Concat",
            &["obs_norm", "eps", "c"],
            "x0",
            vec![int_attr("axis", 1)],
        ),
    ];
    let p = w.mean.params();
    let mut x = "x0".to_string();
    for l in 0..layout.n_layers() {
        let (n_in, n_out) = (sizes[l], sizes[l + 1]);
        let (wo, bo) = layout.offsets(l);
        let (wn, bn) = (format!("w{l}"), format!("b{l}"));
        inits.push(initializer(&wn, &[n_out, n_in], &p[wo..wo + n_in * n_out]));
        inits.push(initializer(&bn, &[n_out], &p[bo..bo + n_out]));
        let gemm = format!("gemm{l}");
        nodes.push(node(
            "Gemm",
            &[&x, &wn, &bn],
            &gemm,
            vec![int_attr("transB", 1)],
        ));
        x = if l + 1 == layout.n_layers() {
            "action".into()
        } else {
            format!("h{l}")
        };
        nodes.push(node("Tanh", &[&gemm], &x, vec![]));
    }
    let graph = GraphProto {
        name: Some("ess_policy".into()),
        node: nodes,
        initializer: inits,
        input: vec![
            float_input("obs", od),
            float_input("eps", 1),
            float_input("c", n_codes),
        ],
        output: vec![float_input("action", ad)],
        doc_string: Some(
            "action = tanh(MLP(concat((obs - obs_mean) / obs_std, eps, c))); obs raw, eps in \
             [-1, 1] (0 without it), c one-hot"
                .into(),
        ),
        ..Default::default()
    };
    ModelProto {
        ir_version: Some(IR_VERSION),
        opset_import: vec![OperatorSetIdProto {
            domain: Some(String::new()),
            version: Some(OPSET),
        }],
        producer_name: Some("ess".into()),
        producer_version: Some(env!("CARGO_PKG_VERSION").into()),
        doc_string: Some(
            "An Ess policy (ess export --onnx); inputs obs, eps, c; output action.".into(),
        ),
        graph: Some(graph),
        metadata_props: meta
            .iter()
            .map(|(k, v)| StringStringEntryProto {
                key: Some(k.clone()),
                value: Some(v.clone()),
            })
            .collect(),
        ..Default::default()
    }
}
