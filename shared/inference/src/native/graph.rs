//! The ONNX file as the native runtime sees it: nodes with their attributes, and every constant
//! (initializers and `Constant` nodes) decoded to f32 or i64 values.
//!
//! The protobuf is parsed with tract-onnx's generated types ([`tract_onnx::pb`]); nothing else of
//! tract is used. `Identity` nodes become aliases. Anything the plans cannot run is refused with a
//! [`Unsupported`] error that names the node.
use std::collections::HashMap;
use tract_onnx::pb;
use tract_onnx::prelude::Framework;

/// Why a graph cannot run on the native runtime; names the node when there is one.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Unsupported {
    /// The node's name (or output name when unnamed); empty for graph-level problems.
    pub node: String,
    /// The node's operator type.
    pub op: String,
    /// What is not supported.
    pub reason: String,
    /// Whether the graph's interface (input or output names) is what differs, rather than an
    /// operator.
    pub interface: bool,
}

impl std::fmt::Display for Unsupported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.node.is_empty() {
            write!(f, "{}", self.reason)
        } else {
            write!(
                f,
                "node `{}` ({}) is not supported by the native runtime: {}",
                self.node, self.op, self.reason
            )
        }
    }
}

impl std::error::Error for Unsupported {}

/// A graph-level error (no node).
pub fn graph_error(reason: impl Into<String>) -> Unsupported {
    Unsupported {
        node: String::new(),
        op: String::new(),
        reason: reason.into(),
        interface: false,
    }
}

/// The graph's inputs or outputs are not the expected ones.
pub fn interface_error(reason: impl Into<String>) -> Unsupported {
    Unsupported {
        interface: true,
        ..graph_error(reason)
    }
}

/// A constant's values.
#[derive(Debug, Clone, PartialEq)]
pub enum ConstValues {
    /// Float values.
    F32(Vec<f32>),
    /// Integer values (shapes, indices, axes).
    I64(Vec<i64>),
}

/// A constant tensor of the graph.
#[derive(Debug, Clone, PartialEq)]
pub struct Const {
    /// Dimensions (empty for a scalar).
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub values: ConstValues,
}

impl Const {
    /// Whether it has no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        match &self.values {
            ConstValues::F32(v) => v.len(),
            ConstValues::I64(v) => v.len(),
        }
    }

    /// The values as f32 (integers converted).
    pub fn f32s(&self) -> Vec<f32> {
        match &self.values {
            ConstValues::F32(v) => v.clone(),
            ConstValues::I64(v) => v.iter().map(|&x| x as f32).collect(),
        }
    }

    /// The values as i64, if they are integers.
    pub fn i64s(&self) -> Option<&[i64]> {
        match &self.values {
            ConstValues::I64(v) => Some(v),
            ConstValues::F32(_) => None,
        }
    }
}

/// One node (not `Constant` or `Identity`, which are resolved at import).
#[derive(Debug, Clone)]
pub struct Node {
    /// The node's name, or its first output's when unnamed.
    pub name: String,
    /// Operator type.
    pub op: String,
    /// Input value names (after aliasing; `""` = an omitted optional input).
    pub inputs: Vec<String>,
    /// Output value names.
    pub outputs: Vec<String>,
    attrs: Vec<pb::AttributeProto>,
}

impl Node {
    /// An [`Unsupported`] error for this node.
    pub fn refuse(&self, reason: impl Into<String>) -> Unsupported {
        Unsupported {
            node: self.name.clone(),
            op: self.op.clone(),
            reason: reason.into(),
            interface: false,
        }
    }

    /// Refuses any attribute not in `known`.
    pub fn only_attributes(&self, known: &[&str]) -> Result<(), Unsupported> {
        for a in &self.attrs {
            if !known.contains(&a.name.as_str()) {
                return Err(self.refuse(format!("attribute `{}`", a.name)));
            }
        }
        Ok(())
    }

    fn attr(&self, name: &str) -> Option<&pb::AttributeProto> {
        self.attrs.iter().find(|a| a.name == name)
    }

    /// Integer list attribute `name`, if present.
    pub fn ints(&self, name: &str) -> Option<&[i64]> {
        self.attr(name).map(|a| a.ints.as_slice())
    }

    /// Integer attribute `name`, else `default`.
    pub fn int(&self, name: &str, default: i64) -> i64 {
        self.attr(name).map_or(default, |a| a.i)
    }

    /// Float attribute `name`, else `default`.
    pub fn float(&self, name: &str, default: f32) -> f32 {
        self.attr(name).map_or(default, |a| a.f)
    }

    /// String attribute `name`, if present.
    pub fn string(&self, name: &str) -> Option<String> {
        self.attr(name)
            .map(|a| String::from_utf8_lossy(&a.s).into_owned())
    }

    /// Checks the input count lies in `min..=max`.
    pub fn input_count(&self, min: usize, max: usize) -> Result<(), Unsupported> {
        let n = self.inputs.len();
        if n < min || n > max {
            return Err(self.refuse(format!("{n} inputs, expected {min}..={max}")));
        }
        if self.outputs.len() != 1 {
            return Err(self.refuse(format!("{} outputs, expected 1", self.outputs.len())));
        }
        Ok(())
    }
}

/// The parsed graph.
#[derive(Debug, Clone)]
pub struct Graph {
    /// Nodes in file order (ONNX requires topological order; the plans check it).
    pub nodes: Vec<Node>,
    /// Every constant by value name.
    pub consts: HashMap<String, Const>,
    /// Graph inputs that are not constants.
    pub inputs: Vec<String>,
    /// Graph output names (after aliasing, in graph order) with their declared names.
    pub outputs: Vec<(String, String)>,
}

impl Graph {
    /// Parses an ONNX model.
    pub fn parse(bytes: &[u8]) -> Result<Self, Unsupported> {
        let model = tract_onnx::onnx()
            .proto_model_for_read(&mut &bytes[..])
            .map_err(|e| graph_error(format!("not an ONNX model: {e}")))?;
        for op in &model.opset_import {
            if (op.domain.is_empty() || op.domain == "ai.onnx") && op.version > 22 {
                return Err(graph_error(format!(
                    "opset {} is newer than the native runtime knows (≤ 22)",
                    op.version
                )));
            }
        }
        let g = model
            .graph
            .ok_or_else(|| graph_error("the model has no graph"))?;
        let mut consts = HashMap::new();
        for t in &g.initializer {
            consts.insert(t.name.clone(), decode_tensor(t, &t.name)?);
        }
        let mut alias: HashMap<String, String> = HashMap::new();
        let resolve = |alias: &HashMap<String, String>, n: &str| -> String {
            let mut cur = n.to_string();
            while let Some(next) = alias.get(&cur) {
                cur = next.clone();
            }
            cur
        };
        let mut nodes = Vec::new();
        for n in &g.node {
            let name = if n.name.is_empty() {
                n.output.first().cloned().unwrap_or_default()
            } else {
                n.name.clone()
            };
            if !(n.domain.is_empty() || n.domain == "ai.onnx") {
                return Err(Unsupported {
                    node: name,
                    op: n.op_type.clone(),
                    reason: format!("operator domain `{}`", n.domain),
                    interface: false,
                });
            }
            let node = Node {
                name,
                op: n.op_type.clone(),
                inputs: n.input.iter().map(|i| resolve(&alias, i)).collect(),
                outputs: n.output.clone(),
                attrs: n.attribute.clone(),
            };
            match node.op.as_str() {
                "Constant" => {
                    node.input_count(0, 0)?;
                    let a = node
                        .attrs
                        .first()
                        .filter(|_| node.attrs.len() == 1)
                        .ok_or_else(|| node.refuse("expected exactly one attribute"))?;
                    let c = match a.name.as_str() {
                        "value" => decode_tensor(
                            a.t.as_ref()
                                .ok_or_else(|| node.refuse("`value` holds no tensor"))?,
                            &node.name,
                        )?,
                        "value_float" => Const {
                            shape: vec![],
                            values: ConstValues::F32(vec![a.f]),
                        },
                        "value_floats" => Const {
                            shape: vec![a.floats.len()],
                            values: ConstValues::F32(a.floats.clone()),
                        },
                        "value_int" => Const {
                            shape: vec![],
                            values: ConstValues::I64(vec![a.i]),
                        },
                        "value_ints" => Const {
                            shape: vec![a.ints.len()],
                            values: ConstValues::I64(a.ints.clone()),
                        },
                        other => return Err(node.refuse(format!("attribute `{other}`"))),
                    };
                    consts.insert(node.outputs[0].clone(), c);
                }
                "Identity" => {
                    node.input_count(1, 1)?;
                    node.only_attributes(&[])?;
                    alias.insert(node.outputs[0].clone(), node.inputs[0].clone());
                }
                _ => nodes.push(node),
            }
        }
        let inputs = g
            .input
            .iter()
            .map(|i| i.name.clone())
            .filter(|n| !consts.contains_key(n))
            .collect();
        let outputs = g
            .output
            .iter()
            .map(|o| (resolve(&alias, &o.name), o.name.clone()))
            .collect();
        Ok(Self {
            nodes,
            consts,
            inputs,
            outputs,
        })
    }

    /// The constant named `name`, if it is one.
    pub fn constant(&self, name: &str) -> Option<&Const> {
        self.consts.get(name)
    }

    /// How many nodes read each value, graph outputs counted as readers.
    pub fn reader_counts(&self) -> HashMap<String, usize> {
        let mut counts: HashMap<String, usize> = HashMap::new();
        for n in &self.nodes {
            for i in n.inputs.iter().filter(|i| !i.is_empty()) {
                *counts.entry(i.clone()).or_default() += 1;
            }
        }
        for (o, _) in &self.outputs {
            *counts.entry(o.clone()).or_default() += 1;
        }
        counts
    }
}

/// Decodes an f32 or integer tensor (raw little-endian bytes or the typed fields).
fn decode_tensor(t: &pb::TensorProto, owner: &str) -> Result<Const, Unsupported> {
    let refuse = |reason: String| Unsupported {
        node: owner.to_string(),
        op: "constant".into(),
        reason,
        interface: false,
    };
    if t.data_location == Some(pb::tensor_proto::DataLocation::External as i32) {
        return Err(refuse("external tensor data".into()));
    }
    let mut shape = Vec::with_capacity(t.dims.len());
    for &d in &t.dims {
        if !(0..=1 << 31).contains(&d) {
            return Err(refuse(format!("dimension {d}")));
        }
        shape.push(d as usize);
    }
    let numel = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|&n| n <= 1 << 31)
        .ok_or_else(|| refuse(format!("shape {shape:?} is too large")))?;
    use pb::tensor_proto::DataType;
    let dt = DataType::try_from(t.data_type).map_err(|_| refuse("unknown data type".into()))?;
    let raw = &t.raw_data;
    let values = match dt {
        DataType::Float => ConstValues::F32(if raw.is_empty() {
            t.float_data.clone()
        } else {
            raw.chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect()
        }),
        DataType::Int64 => ConstValues::I64(if raw.is_empty() {
            t.int64_data.clone()
        } else {
            raw.chunks_exact(8)
                .map(|b| i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
                .collect()
        }),
        DataType::Int32 => ConstValues::I64(if raw.is_empty() {
            t.int32_data.iter().map(|&v| v as i64).collect()
        } else {
            raw.chunks_exact(4)
                .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as i64)
                .collect()
        }),
        other => return Err(refuse(format!("data type {other:?}"))),
    };
    let c = Const { shape, values };
    if c.len() != numel {
        return Err(refuse(format!(
            "{} values for shape {:?}",
            c.len(),
            c.shape
        )));
    }
    Ok(c)
}
