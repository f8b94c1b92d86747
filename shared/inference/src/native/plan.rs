//! The U-Net's fused op plan: the ONNX graph of 5-D convolutions turned into a short list of
//! [`ConvOp`]s, each one kernel pass that writes one channels-last buffer.
//!
//! Supported nodes: `Conv` (3³ stride 1 pad 1, 1³, 2³ stride 2 pad 0; no groups or dilation),
//! `ConvTranspose` (2³ stride 2 pad 0), `BatchNormalization` (inference form, folded into the
//! convolution before it), `Add`, `Relu`, `Concat` on the channel axis (and `Identity`,
//! `Constant`, resolved at import). Fusions, each only where the fused value has no other reader:
//!
//! * batch norm → the convolution's weights and bias;
//! * `Add` of two convolutions of the same output grid → one op with both weight sets as terms
//!   (the residual block's 1³ skip convolution joins the second 3³ convolution);
//! * `Add` of a convolution and a computed tensor → a residual added in the kernel's epilogue;
//! * `Relu` → the epilogue;
//! * `Concat` → no copy: a convolution of a concatenation is a sum of one term per part.
//!
//! Everything else is refused at load with the node named (`Unsupported`).
use super::graph::{Graph, Node, Unsupported};
use std::collections::HashMap;

/// One channels-last buffer of the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BufInfo {
    /// Grid dimensions (X, Y, Z).
    pub dims: [usize; 3],
    /// Channels of the value.
    pub channels: usize,
    /// Floats per voxel in the buffer (channels rounded up to 8 for kernel outputs).
    pub stride: usize,
}

/// The footprint of one term of a convolution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TermKind {
    /// 3³, stride 1, zero padding 1.
    K3,
    /// 1³.
    K1,
    /// 2³, stride 2, no padding (the encoder's down-sampling).
    Down2,
    /// Transposed 2³, stride 2 (the decoder's up-sampling).
    Up2,
}

/// One input of a convolution: a buffer and the weights that read it.
#[derive(Debug, Clone)]
pub struct Term {
    /// Input buffer.
    pub input: usize,
    /// Footprint.
    pub kind: TermKind,
    /// Input channels read.
    pub cin: usize,
    /// ONNX weights of this input's channels: `[cout][cin][k][k][k]` (Conv) or
    /// `[cin][cout][2][2][2]` (`Up2`).
    pub weights: Vec<f32>,
}

impl Term {
    fn kernel_volume(&self) -> usize {
        match self.kind {
            TermKind::K3 => 27,
            TermKind::K1 => 1,
            TermKind::Down2 | TermKind::Up2 => 8,
        }
    }

    /// Multiply-adds per output voxel.
    pub fn macs_per_output(&self, cout: usize) -> usize {
        match self.kind {
            TermKind::Up2 => self.cin * cout,
            _ => self.kernel_volume() * self.cin * cout,
        }
    }
}

/// One fused kernel pass: `out = relu?(bias + Σ terms + residual)`.
#[derive(Debug, Clone)]
pub struct ConvOp {
    /// The ONNX nodes fused into it, for messages.
    pub nodes: Vec<String>,
    /// Inputs with their weights (all `Up2`, or none of them).
    pub terms: Vec<Term>,
    /// Bias per output channel (batch norm folded).
    pub bias: Vec<f32>,
    /// Output channels.
    pub cout: usize,
    /// Output buffer.
    pub out: usize,
    /// Buffer added before the activation.
    pub residual: Option<usize>,
    /// ReLU at the end.
    pub relu: bool,
}

impl ConvOp {
    /// Whether this op up-samples (its terms are transposed convolutions).
    pub fn is_transpose(&self) -> bool {
        self.terms.iter().any(|t| t.kind == TermKind::Up2)
    }
}

/// The whole U-Net as buffers and ops in execution order.
#[derive(Debug, Clone)]
pub struct UnetPlan {
    /// Every buffer (index 0 is the input).
    pub bufs: Vec<BufInfo>,
    /// Ops in execution order.
    pub ops: Vec<ConvOp>,
    /// Buffer of each requested output.
    pub outputs: Vec<usize>,
}

/// What a graph value is during planning.
#[derive(Debug, Clone)]
enum Val {
    Buf(usize),
    Concat(Vec<usize>),
}

/// How far an op's epilogue has been fused (fusions must come in this order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd)]
enum Stage {
    Raw,
    Added,
    Activated,
}

struct Builder<'g> {
    graph: &'g Graph,
    readers: HashMap<String, usize>,
    vals: HashMap<String, Val>,
    bufs: Vec<BufInfo>,
    ops: Vec<Option<(ConvOp, Stage)>>,
    /// Op slot producing each buffer.
    producer: HashMap<usize, usize>,
}

fn round8(c: usize) -> usize {
    c.div_ceil(8) * 8
}

impl UnetPlan {
    /// Plans `graph` for the input `input` of shape `[1, C, X, Y, Z]`, producing `outputs`
    /// (declared graph output names).
    pub fn build(
        graph: &Graph,
        input: &str,
        input_shape: &[usize],
        outputs: &[String],
    ) -> Result<Self, Unsupported> {
        let err = |r: String| super::graph::graph_error(r);
        if input_shape.len() != 5 || input_shape[0] != 1 {
            return Err(err(format!(
                "input shape {input_shape:?} is not [1, C, X, Y, Z]"
            )));
        }
        if graph.inputs != [input] {
            return Err(super::graph::interface_error(format!(
                "inputs are {:?}, expected [{input:?}]",
                graph.inputs
            )));
        }
        let mut b = Builder {
            graph,
            readers: graph.reader_counts(),
            vals: HashMap::new(),
            bufs: vec![BufInfo {
                dims: [input_shape[2], input_shape[3], input_shape[4]],
                channels: input_shape[1],
                stride: input_shape[1],
            }],
            ops: Vec::new(),
            producer: HashMap::new(),
        };
        b.vals.insert(input.to_string(), Val::Buf(0));
        for node in &graph.nodes {
            b.node(node)?;
        }
        let mut out_bufs = Vec::with_capacity(outputs.len());
        for name in outputs {
            let resolved = graph
                .outputs
                .iter()
                .find(|(_, declared)| declared == name)
                .map(|(r, _)| r)
                .ok_or_else(|| {
                    super::graph::interface_error(format!("no output named `{name}`"))
                })?;
            match b.vals.get(resolved) {
                Some(Val::Buf(id)) if *id != 0 => out_bufs.push(*id),
                _ => {
                    return Err(err(format!(
                        "output `{name}` is not the result of a convolution"
                    )))
                }
            }
        }
        // Compact: drop merged slots and buffers nobody writes or reads.
        let ops: Vec<ConvOp> = b.ops.into_iter().flatten().map(|(op, _)| op).collect();
        Ok(Self {
            bufs: b.bufs,
            ops,
            outputs: out_bufs,
        })
    }

    /// Multiply-adds of the whole plan on a dense grid.
    pub fn dense_macs(&self) -> u64 {
        self.ops
            .iter()
            .map(|op| {
                let d = self.bufs[op.out].dims;
                let per: usize = op.terms.iter().map(|t| t.macs_per_output(op.cout)).sum();
                let voxels = if op.is_transpose() {
                    d[0] * d[1] * d[2] / 8
                } else {
                    d[0] * d[1] * d[2]
                };
                (per * voxels) as u64
            })
            .sum()
    }
}

impl Builder<'_> {
    fn val(&self, node: &Node, name: &str) -> Result<Val, Unsupported> {
        if self.graph.constant(name).is_some() {
            return Err(node.refuse(format!(
                "input `{name}` is a constant where a grid is expected"
            )));
        }
        self.vals
            .get(name)
            .cloned()
            .ok_or_else(|| node.refuse(format!("input `{name}` is not computed before it")))
    }

    fn parts(&self, node: &Node, name: &str) -> Result<Vec<usize>, Unsupported> {
        Ok(match self.val(node, name)? {
            Val::Buf(b) => vec![b],
            Val::Concat(p) => p,
        })
    }

    fn new_buf(&mut self, dims: [usize; 3], channels: usize) -> usize {
        self.bufs.push(BufInfo {
            dims,
            channels,
            stride: round8(channels),
        });
        self.bufs.len() - 1
    }

    /// The op that alone reads `name` (a convolution output with one reader), taken out of
    /// its slot to be re-appended after fusion.
    fn fusable(&mut self, node: &Node, name: &str, max_stage: Stage) -> Option<(ConvOp, Stage)> {
        let Some(Val::Buf(b)) = self.vals.get(name) else {
            return None;
        };
        if self.readers.get(name).copied() != Some(1) {
            return None;
        }
        let slot = *self.producer.get(b)?;
        let stage = self.ops[slot].as_ref()?.1;
        if stage > max_stage {
            return None;
        }
        let _ = node;
        self.ops[slot].take()
    }

    fn push(&mut self, name: &str, op: ConvOp, stage: Stage) {
        let out = op.out;
        self.ops.push(Some((op, stage)));
        self.producer.insert(out, self.ops.len() - 1);
        self.vals.insert(name.to_string(), Val::Buf(out));
    }

    fn node(&mut self, node: &Node) -> Result<(), Unsupported> {
        match node.op.as_str() {
            "Conv" => self.conv(node),
            "ConvTranspose" => self.conv_transpose(node),
            "BatchNormalization" => self.batch_norm(node),
            "Relu" => {
                node.input_count(1, 1)?;
                node.only_attributes(&[])?;
                let (mut op, _) = self
                    .fusable(node, &node.inputs[0], Stage::Added)
                    .ok_or_else(|| {
                        node.refuse("its input is not a convolution output read only by it")
                    })?;
                op.relu = true;
                op.nodes.push(node.name.clone());
                self.push(&node.outputs[0], op, Stage::Activated);
                Ok(())
            }
            "Add" => self.add(node),
            "Concat" => {
                node.only_attributes(&["axis"])?;
                if node.inputs.is_empty() || node.outputs.len() != 1 {
                    return Err(node.refuse("expected inputs and one output"));
                }
                let axis = node.int("axis", 0);
                if axis != 1 && axis != -4 {
                    return Err(
                        node.refuse(format!("axis {axis}: only channels (1) are supported"))
                    );
                }
                let mut parts = Vec::new();
                for i in &node.inputs {
                    parts.extend(self.parts(node, i)?);
                }
                let dims = self.bufs[parts[0]].dims;
                if parts.iter().any(|&p| self.bufs[p].dims != dims) {
                    return Err(node.refuse("inputs of different grid sizes"));
                }
                self.vals
                    .insert(node.outputs[0].clone(), Val::Concat(parts));
                Ok(())
            }
            other => Err(node.refuse(format!(
                "operator {other} is outside the native U-Net subset (Conv, ConvTranspose, \
                 BatchNormalization, Add, Relu, Concat, Identity, Constant)"
            ))),
        }
    }

    fn weights(&self, node: &Node, idx: usize, shape: &[usize]) -> Result<Vec<f32>, Unsupported> {
        let name = node
            .inputs
            .get(idx)
            .filter(|n| !n.is_empty())
            .ok_or_else(|| node.refuse(format!("input {idx} is missing")))?;
        let c = self
            .graph
            .constant(name)
            .ok_or_else(|| node.refuse(format!("input `{name}` is not a constant")))?;
        if c.shape != shape {
            return Err(node.refuse(format!(
                "`{name}` has shape {:?}, expected {shape:?}",
                c.shape
            )));
        }
        match &c.values {
            super::graph::ConstValues::F32(v) => Ok(v.clone()),
            _ => Err(node.refuse(format!("`{name}` is not f32"))),
        }
    }

    /// Kernel size, stride and pad of a Conv/ConvTranspose, checked to be cubic and plain.
    fn geometry(
        &self,
        node: &Node,
        wshape: &[usize],
    ) -> Result<(usize, usize, usize), Unsupported> {
        let ints = |name: &str, n: usize, default: i64| -> Result<Vec<i64>, Unsupported> {
            match node.ints(name) {
                Some(v) if v.len() == n => Ok(v.to_vec()),
                Some(v) => Err(node.refuse(format!("`{name}` = {v:?}"))),
                None => Ok(vec![default; n]),
            }
        };
        if wshape.len() != 5 {
            return Err(node.refuse(format!("weights of rank {} (only 3-D)", wshape.len())));
        }
        if let Some(p) = node.string("auto_pad") {
            if p != "NOTSET" {
                return Err(node.refuse(format!("auto_pad = {p}")));
            }
        }
        if node.int("group", 1) != 1 {
            return Err(node.refuse("grouped convolution"));
        }
        if ints("dilations", 3, 1)?.iter().any(|&d| d != 1) {
            return Err(node.refuse("dilation"));
        }
        let k = wshape[2];
        let kernel = ints("kernel_shape", 3, k as i64)?;
        let strides = ints("strides", 3, 1)?;
        let pads = ints("pads", 6, 0)?;
        let cubic = |v: &[i64], x: i64| v.iter().all(|&a| a == x);
        if !cubic(&kernel, k as i64) || wshape[3] != k || wshape[4] != k {
            return Err(node.refuse(format!("kernel {kernel:?} is not cubic")));
        }
        if !cubic(&strides, strides[0]) || !cubic(&pads, pads[0]) {
            return Err(node.refuse(format!(
                "strides {strides:?} / pads {pads:?} differ between axes"
            )));
        }
        Ok((k, strides[0].max(0) as usize, pads[0].max(0) as usize))
    }

    fn conv(&mut self, node: &Node) -> Result<(), Unsupported> {
        node.input_count(2, 3)?;
        node.only_attributes(&[
            "auto_pad",
            "dilations",
            "group",
            "kernel_shape",
            "pads",
            "strides",
        ])?;
        let parts = self.parts(node, &node.inputs[0])?;
        let cin: usize = parts.iter().map(|&p| self.bufs[p].channels).sum();
        let wshape = self
            .graph
            .constant(&node.inputs[1])
            .map(|c| c.shape.clone())
            .ok_or_else(|| node.refuse("weights are not a constant"))?;
        let (k, s, p) = self.geometry(node, &wshape)?;
        if wshape[1] != cin {
            return Err(node.refuse(format!(
                "weights for {} input channels, the input has {cin}",
                wshape[1]
            )));
        }
        let kind = match (k, s, p) {
            (3, 1, 1) => TermKind::K3,
            (1, 1, 0) => TermKind::K1,
            (2, 2, 0) => TermKind::Down2,
            _ => {
                return Err(node.refuse(format!(
                    "kernel {k}³ stride {s} pad {p} (supported: 3³ stride 1 pad 1, 1³, 2³ stride 2)"
                )))
            }
        };
        let cout = wshape[0];
        let w = self.weights(node, 1, &wshape)?;
        let bias = if node.inputs.len() == 3 && !node.inputs[2].is_empty() {
            self.weights(node, 2, &[cout])?
        } else {
            vec![0.0; cout]
        };
        let mut dims = self.bufs[parts[0]].dims;
        if kind == TermKind::Down2 {
            if dims.iter().any(|d| d % 2 != 0) {
                return Err(node.refuse(format!("stride 2 on odd grid {dims:?}")));
            }
            dims = dims.map(|d| d / 2);
        }
        let kv = k * k * k;
        let mut terms = Vec::new();
        let mut c0 = 0;
        for &part in &parts {
            let pc = self.bufs[part].channels;
            let mut tw = Vec::with_capacity(cout * pc * kv);
            for co in 0..cout {
                let base = (co * cin + c0) * kv;
                tw.extend_from_slice(&w[base..base + pc * kv]);
            }
            terms.push(Term {
                input: part,
                kind,
                cin: pc,
                weights: tw,
            });
            c0 += pc;
        }
        let out = self.new_buf(dims, cout);
        let op = ConvOp {
            nodes: vec![node.name.clone()],
            terms,
            bias,
            cout,
            out,
            residual: None,
            relu: false,
        };
        self.push(&node.outputs[0], op, Stage::Raw);
        Ok(())
    }

    fn conv_transpose(&mut self, node: &Node) -> Result<(), Unsupported> {
        node.input_count(2, 3)?;
        node.only_attributes(&[
            "auto_pad",
            "dilations",
            "group",
            "kernel_shape",
            "pads",
            "strides",
            "output_padding",
        ])?;
        if node
            .ints("output_padding")
            .is_some_and(|v| v.iter().any(|&x| x != 0))
        {
            return Err(node.refuse("output_padding"));
        }
        let parts = self.parts(node, &node.inputs[0])?;
        let cin: usize = parts.iter().map(|&p| self.bufs[p].channels).sum();
        let wshape = self
            .graph
            .constant(&node.inputs[1])
            .map(|c| c.shape.clone())
            .ok_or_else(|| node.refuse("weights are not a constant"))?;
        let (k, s, p) = self.geometry(node, &wshape)?;
        if (k, s, p) != (2, 2, 0) {
            return Err(node.refuse(format!(
                "kernel {k}³ stride {s} pad {p} (supported: 2³ stride 2)"
            )));
        }
        if wshape[0] != cin {
            return Err(node.refuse(format!(
                "weights for {} input channels, the input has {cin}",
                wshape[0]
            )));
        }
        let cout = wshape[1];
        let w = self.weights(node, 1, &wshape)?;
        let bias = if node.inputs.len() == 3 && !node.inputs[2].is_empty() {
            self.weights(node, 2, &[cout])?
        } else {
            vec![0.0; cout]
        };
        let dims = self.bufs[parts[0]].dims.map(|d| d * 2);
        let mut terms = Vec::new();
        let mut c0 = 0;
        for &part in &parts {
            let pc = self.bufs[part].channels;
            terms.push(Term {
                input: part,
                kind: TermKind::Up2,
                cin: pc,
                weights: w[c0 * cout * 8..(c0 + pc) * cout * 8].to_vec(),
            });
            c0 += pc;
        }
        let out = self.new_buf(dims, cout);
        let op = ConvOp {
            nodes: vec![node.name.clone()],
            terms,
            bias,
            cout,
            out,
            residual: None,
            relu: false,
        };
        self.push(&node.outputs[0], op, Stage::Raw);
        Ok(())
    }

    fn batch_norm(&mut self, node: &Node) -> Result<(), Unsupported> {
        node.input_count(5, 5)?;
        node.only_attributes(&["epsilon", "momentum", "training_mode", "spatial"])?;
        if node.int("training_mode", 0) != 0 || node.int("spatial", 1) != 1 {
            return Err(node.refuse("training mode / non-spatial batch norm"));
        }
        let eps = node.float("epsilon", 1e-5);
        let (mut op, _) = self
            .fusable(node, &node.inputs[0], Stage::Raw)
            .ok_or_else(|| {
                node.refuse("its input is not a convolution output read only by it (cannot fold)")
            })?;
        let c = op.cout;
        let p: Vec<Vec<f32>> = (1..5)
            .map(|i| self.weights(node, i, &[c]))
            .collect::<Result<_, _>>()?;
        let (scale, shift, mean, var) = (&p[0], &p[1], &p[2], &p[3]);
        let s: Vec<f32> = (0..c).map(|i| scale[i] / (var[i] + eps).sqrt()).collect();
        for t in &mut op.terms {
            let per = t.weights.len() / (t.cin * c).max(1);
            for (i, w) in t.weights.iter_mut().enumerate() {
                let co = if t.kind == TermKind::Up2 {
                    (i / per) % c
                } else {
                    i / (t.cin * per)
                };
                *w *= s[co];
            }
        }
        for i in 0..c {
            op.bias[i] = (op.bias[i] - mean[i]) * s[i] + shift[i];
        }
        op.nodes.push(node.name.clone());
        self.push(&node.outputs[0], op, Stage::Raw);
        Ok(())
    }

    fn add(&mut self, node: &Node) -> Result<(), Unsupported> {
        node.input_count(2, 2)?;
        node.only_attributes(&[])?;
        let (a, b) = (&node.inputs[0], &node.inputs[1]);
        // Two convolutions of the same grid: one op with both weight sets.
        if let (Some(x), Some(y)) = (self.peek(a), self.peek(b)) {
            let (ox, oy) = (&x.0, &y.0);
            if x.1 == Stage::Raw
                && y.1 == Stage::Raw
                && !ox.is_transpose()
                && !oy.is_transpose()
                && ox.cout == oy.cout
                && self.bufs[ox.out].dims == self.bufs[oy.out].dims
            {
                let (mut op, _) = self.fusable(node, a, Stage::Raw).expect("peeked");
                let (other, _) = self.fusable(node, b, Stage::Raw).expect("peeked");
                op.terms.extend(other.terms);
                for (b0, b1) in op.bias.iter_mut().zip(&other.bias) {
                    *b0 += b1;
                }
                op.nodes.extend(other.nodes);
                op.nodes.push(node.name.clone());
                self.push(&node.outputs[0], op, Stage::Added);
                return Ok(());
            }
        }
        // A convolution plus a computed tensor: residual in the epilogue.
        for (conv, other) in [(a, b), (b, a)] {
            if self.peek(conv).is_none_or(|(_, s)| s != Stage::Raw) {
                continue;
            }
            let Ok(Val::Buf(r)) = self.val(node, other) else {
                continue;
            };
            let (mut op, _) = self.fusable(node, conv, Stage::Raw).expect("peeked");
            let ob = self.bufs[op.out];
            let rb = self.bufs[r];
            if ob.dims != rb.dims || ob.channels != rb.channels {
                return Err(node.refuse(format!(
                    "operands of different shapes ({:?}×{} and {:?}×{}); broadcasting is not supported",
                    ob.dims, ob.channels, rb.dims, rb.channels
                )));
            }
            op.residual = Some(r);
            op.nodes.push(node.name.clone());
            self.push(&node.outputs[0], op, Stage::Added);
            return Ok(());
        }
        Err(node.refuse(
            "neither operand is a convolution output read only by this Add (standalone additions \
             are not supported)",
        ))
    }

    /// The op and stage that alone produce `name`, without taking it.
    fn peek(&self, name: &str) -> Option<(ConvOp, Stage)> {
        let Some(Val::Buf(b)) = self.vals.get(name) else {
            return None;
        };
        if self.readers.get(name).copied() != Some(1) {
            return None;
        }
        let slot = *self.producer.get(b)?;
        self.ops[slot].clone()
    }
}
