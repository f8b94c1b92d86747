//! The MLP head on the native runtime: a chain of dense layers (`Gemm`, or `MatMul` + `Add`,
//! with `Relu`) run as blocked matrix products (`matrixmultiply`'s packed sgemm: 63 against 46
//! GFLOP/s for our own unpacked kernel and 50–67 for the `gemm` crate, one thread, 256 × 256
//! layer; docs/benchmarks.md) with the bias preloaded and the ReLU applied while the block is in
//! the cache, then the element-wise tail that turns the last layer's raw outputs into the named outputs
//! (`Slice`/`Gather` of columns, `Mul`, `Add`, `Sub`, `Div`, `ReduceSum` over the columns,
//! `Sqrt`, `Sigmoid`, `Softplus`, `Reciprocal`, `Relu`, `Exp`, `Clip`).
//!
//! Rows run in blocks of [`BLOCK_ROWS`] through every layer and the tail while they are in the
//! cache, the blocks spread over the thread pool.
use super::graph::{Graph, Node, Unsupported};
use std::collections::HashMap;

/// Rows per block.
pub const BLOCK_ROWS: usize = 256;

/// One dense layer: `out = act(in · W + b)`.
#[derive(Debug, Clone)]
struct Dense {
    /// Input width (real).
    k: usize,
    /// Output width and its padding to 8.
    n: usize,
    np: usize,
    /// `[k][np]`.
    w: Vec<f32>,
    /// `[np]`.
    b: Vec<f32>,
    relu: bool,
}

/// An operand of an element-wise op.
#[derive(Debug, Clone, PartialEq)]
enum Operand {
    Slot(usize),
    Scalar(f32),
    /// A constant row broadcast over the rows.
    Row(Vec<f32>),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Binary {
    Add,
    Sub,
    Mul,
    Div,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Unary {
    Sqrt,
    Sigmoid,
    Softplus,
    Reciprocal,
    Relu,
    Exp,
}

#[derive(Debug, Clone, PartialEq)]
enum TailOp {
    Take { src: usize, cols: Vec<usize> },
    Binary { op: Binary, a: Operand, b: Operand },
    Unary { op: Unary, src: usize },
    Clip { src: usize, lo: f32, hi: f32 },
    ReduceSum { src: usize },
}

/// A value of the tail: `rows × cols`, rank 1 (`[N]`, one column) or 2 (`[N, cols]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct SlotInfo {
    cols: usize,
    rank: usize,
}

/// The MLP graph as dense layers and a tail program.
#[derive(Debug, Clone)]
pub struct MlpPlan {
    layers: Vec<Dense>,
    /// Slot 0 is the last layer's output; op `i` writes slot `i + 1`.
    tail: Vec<TailOp>,
    slots: Vec<SlotInfo>,
    outputs: Vec<usize>,
    in_dim: usize,
}

#[derive(Debug, Clone)]
enum Val {
    Input,
    Layer(usize),
    Slot(usize),
}

impl MlpPlan {
    /// Plans `graph` with input `input` (`[N, in_dim]`) and the named outputs.
    pub fn build(
        graph: &Graph,
        input: &str,
        in_dim: usize,
        outputs: &[&str],
    ) -> Result<Self, Unsupported> {
        let err = |r: String| super::graph::graph_error(r);
        if graph.inputs != [input] {
            return Err(super::graph::interface_error(format!(
                "inputs are {:?}, expected [{input:?}]",
                graph.inputs
            )));
        }
        let readers = graph.reader_counts();
        let mut p = Self {
            layers: Vec::new(),
            tail: Vec::new(),
            slots: Vec::new(),
            outputs: Vec::new(),
            in_dim,
        };
        let mut vals: HashMap<String, Val> = HashMap::new();
        vals.insert(input.to_string(), Val::Input);
        for node in &graph.nodes {
            p.node(graph, node, &readers, &mut vals)?;
        }
        for name in outputs {
            let resolved = graph
                .outputs
                .iter()
                .find(|(_, d)| d == name)
                .map(|(r, _)| r.clone())
                .ok_or_else(|| {
                    super::graph::interface_error(format!("no output named `{name}`"))
                })?;
            match vals.get(&resolved) {
                Some(Val::Slot(s)) => p.outputs.push(*s),
                Some(Val::Layer(l)) if *l + 1 == p.layers.len() => {
                    let s = p.close_chain()?;
                    p.outputs.push(s);
                }
                _ => return Err(err(format!("output `{name}` is not computed by the graph"))),
            }
        }
        if p.layers.is_empty() {
            return Err(err("the MLP has no dense layer".into()));
        }
        Ok(p)
    }

    /// Output `i`'s shape for `n` rows.
    pub fn output_shape(&self, i: usize, n: usize) -> Vec<usize> {
        let s = self.slots[self.outputs[i]];
        if s.rank == 1 {
            vec![n]
        } else {
            vec![n, s.cols]
        }
    }

    /// Multiply-adds per row.
    pub fn macs_per_row(&self) -> usize {
        self.layers.iter().map(|l| l.k * l.n).sum()
    }

    fn close_chain(&mut self) -> Result<usize, Unsupported> {
        if self.slots.is_empty() {
            let last = self.layers.last().ok_or_else(|| {
                super::graph::graph_error("element-wise ops before any dense layer")
            })?;
            self.slots.push(SlotInfo {
                cols: last.n,
                rank: 2,
            });
        }
        Ok(0)
    }

    fn slot_of(
        &mut self,
        node: &Node,
        vals: &HashMap<String, Val>,
        name: &str,
    ) -> Result<usize, Unsupported> {
        match vals.get(name) {
            Some(Val::Slot(s)) => Ok(*s),
            Some(Val::Layer(l)) if *l + 1 == self.layers.len() => self.close_chain(),
            Some(Val::Layer(_)) => Err(node.refuse("reads a hidden layer's output")),
            Some(Val::Input) => Err(node.refuse("element-wise op on the input features")),
            None => Err(node.refuse(format!("input `{name}` is not computed before it"))),
        }
    }

    fn operand(
        &mut self,
        graph: &Graph,
        node: &Node,
        vals: &HashMap<String, Val>,
        name: &str,
    ) -> Result<Operand, Unsupported> {
        if let Some(c) = graph.constant(name) {
            let v = c.f32s();
            return match (c.shape.len(), v.len()) {
                (_, 1) => Ok(Operand::Scalar(v[0])),
                (1, _) => Ok(Operand::Row(v)),
                _ => Err(node.refuse(format!("constant `{name}` of shape {:?}", c.shape))),
            };
        }
        Ok(Operand::Slot(self.slot_of(node, vals, name)?))
    }

    fn info(&self, o: &Operand) -> Option<SlotInfo> {
        match o {
            Operand::Slot(s) => Some(self.slots[*s]),
            _ => None,
        }
    }

    fn push(&mut self, op: TailOp, info: SlotInfo, out: &str, vals: &mut HashMap<String, Val>) {
        self.tail.push(op);
        self.slots.push(info);
        vals.insert(out.to_string(), Val::Slot(self.slots.len() - 1));
    }

    fn const_scalar(graph: &Graph, node: &Node, idx: usize) -> Result<Option<f32>, Unsupported> {
        match node.inputs.get(idx).filter(|n| !n.is_empty()) {
            None => Ok(None),
            Some(name) => match graph.constant(name) {
                Some(c) if c.len() == 1 => Ok(Some(c.f32s()[0])),
                _ => Err(node.refuse(format!("input `{name}` is not a constant scalar"))),
            },
        }
    }

    /// Column indices selected along axis 1 of a rank-2 value by a constant.
    fn axis1(graph: &Graph, node: &Node, idx: usize) -> Result<Option<Vec<i64>>, Unsupported> {
        match node.inputs.get(idx).filter(|n| !n.is_empty()) {
            None => Ok(None),
            Some(name) => graph
                .constant(name)
                .and_then(|c| c.i64s().map(|v| Some(v.to_vec())))
                .ok_or_else(|| node.refuse(format!("input `{name}` is not a constant integer"))),
        }
    }

    fn node(
        &mut self,
        graph: &Graph,
        node: &Node,
        readers: &HashMap<String, usize>,
        vals: &mut HashMap<String, Val>,
    ) -> Result<(), Unsupported> {
        let out = node.outputs.first().cloned().unwrap_or_default();
        if matches!(node.op.as_str(), "Relu" | "Add")
            && self.slots.is_empty()
            && self.fuse_into_layer(graph, node, readers, vals)?
        {
            return Ok(());
        }
        match node.op.as_str() {
            "Gemm" | "MatMul" => {
                node.input_count(2, if node.op == "Gemm" { 3 } else { 2 })?;
                node.only_attributes(&["alpha", "beta", "transA", "transB"])?;
                if !self.slots.is_empty() {
                    return Err(node.refuse("a dense layer after the element-wise tail"));
                }
                let prev_ok = match vals.get(&node.inputs[0]) {
                    Some(Val::Input) => self.layers.is_empty(),
                    Some(Val::Layer(l)) => *l + 1 == self.layers.len(),
                    _ => false,
                };
                if !prev_ok || readers.get(&node.inputs[0]).copied() != Some(1) {
                    return Err(node.refuse("its input is not the previous layer's output (read only by it)"));
                }
                if node.int("transA", 0) != 0 {
                    return Err(node.refuse("transA"));
                }
                let k = self.layers.last().map_or(self.in_dim, |l| l.n);
                let wc = graph
                    .constant(&node.inputs[1])
                    .filter(|c| c.shape.len() == 2)
                    .ok_or_else(|| node.refuse("weights are not a constant matrix"))?;
                let w = wc.f32s();
                let trans = node.int("transB", 0) != 0;
                let (wk, n) = if trans { (wc.shape[1], wc.shape[0]) } else { (wc.shape[0], wc.shape[1]) };
                if wk != k {
                    return Err(node.refuse(format!("weights for {wk} inputs, the input has {k}")));
                }
                let alpha = node.float("alpha", 1.0);
                let beta = node.float("beta", 1.0);
                let np = n.div_ceil(8) * 8;
                let mut packed = vec![0.0; k * np];
                for r in 0..k {
                    for c in 0..n {
                        let v = if trans { w[c * k + r] } else { w[r * n + c] };
                        packed[r * np + c] = alpha * v;
                    }
                }
                let mut b = vec![0.0; np];
                if let Some(name) = node.inputs.get(2).filter(|n| !n.is_empty()) {
                    let c = graph
                        .constant(name)
                        .ok_or_else(|| node.refuse("bias is not a constant"))?;
                    let v = c.f32s();
                    if v.len() == n {
                        b[..n].iter_mut().zip(&v).for_each(|(d, s)| *d = beta * s);
                    } else if v.len() == 1 {
                        b[..n].iter_mut().for_each(|d| *d = beta * v[0]);
                    } else {
                        return Err(node.refuse(format!("bias of shape {:?}", c.shape)));
                    }
                }
                self.layers.push(Dense { k, n, np, w: packed, b, relu: false });
                vals.insert(out, Val::Layer(self.layers.len() - 1));
                Ok(())
            }
            "Slice" => {
                node.input_count(3, 5)?;
                node.only_attributes(&[])?;
                let src = self.slot_of(node, vals, &node.inputs[0])?;
                let info = self.slots[src];
                let starts = Self::axis1(graph, node, 1)?.unwrap_or_default();
                let ends = Self::axis1(graph, node, 2)?.unwrap_or_default();
                let axes = Self::axis1(graph, node, 3)?.unwrap_or(vec![0]);
                let steps = Self::axis1(graph, node, 4)?.unwrap_or(vec![1]);
                if info.rank != 2 || starts.len() != 1 || ends.len() != 1 || !(axes == [1] || axes == [-1]) || steps != [1] {
                    return Err(node.refuse("only a unit-step slice of the columns of a matrix is supported"));
                }
                let clamp = |v: i64| -> usize {
                    let v = if v < 0 { v + info.cols as i64 } else { v };
                    v.clamp(0, info.cols as i64) as usize
                };
                let (s, e) = (clamp(starts[0]), clamp(ends[0]));
                let cols: Vec<usize> = (s..e.max(s)).collect();
                let info = SlotInfo { cols: cols.len(), rank: 2 };
                self.push(TailOp::Take { src, cols }, info, &out, vals);
                Ok(())
            }
            "Gather" => {
                node.input_count(2, 2)?;
                node.only_attributes(&["axis"])?;
                let src = self.slot_of(node, vals, &node.inputs[0])?;
                let info = self.slots[src];
                let axis = node.int("axis", 0);
                let idx = graph.constant(&node.inputs[1]).and_then(|c| c.i64s().map(|v| (c.shape.len(), v.to_vec())));
                let Some((rank, idx)) = idx.filter(|_| info.rank == 2 && (axis == 1 || axis == -1)) else {
                    return Err(node.refuse("only constant column indices of a matrix are supported"));
                };
                let mut cols = Vec::new();
                for &i in &idx {
                    let j = if i < 0 { i + info.cols as i64 } else { i };
                    if !(0..info.cols as i64).contains(&j) {
                        return Err(node.refuse(format!("index {i} out of {} columns", info.cols)));
                    }
                    cols.push(j as usize);
                }
                let info = SlotInfo { cols: cols.len(), rank: if rank == 0 { 1 } else { 2 } };
                self.push(TailOp::Take { src, cols }, info, &out, vals);
                Ok(())
            }
            "Add" | "Sub" | "Mul" | "Div" => {
                node.input_count(2, 2)?;
                node.only_attributes(&[])?;
                let a = self.operand(graph, node, vals, &node.inputs[0])?;
                let b = self.operand(graph, node, vals, &node.inputs[1])?;
                let info = match (self.info(&a), self.info(&b)) {
                    (Some(x), Some(y)) if x == y => x,
                    (Some(x), Some(y)) if x.rank == 2 && y.rank == 2 && (x.cols == 1 || y.cols == 1) => {
                        SlotInfo { cols: x.cols.max(y.cols), rank: 2 }
                    }
                    (Some(x), None) | (None, Some(x)) => {
                        let row = [&a, &b].into_iter().find_map(|o| match o {
                            Operand::Row(r) => Some(r.len()),
                            _ => None,
                        });
                        match row {
                            Some(len) if x.rank != 2 || (len != x.cols && len != 1) => {
                                return Err(node.refuse("a constant row that does not match the columns"))
                            }
                            _ => x,
                        }
                    }
                    _ => return Err(node.refuse("operands that do not broadcast row-wise")),
                };
                let op = match node.op.as_str() {
                    "Add" => Binary::Add,
                    "Sub" => Binary::Sub,
                    "Mul" => Binary::Mul,
                    _ => Binary::Div,
                };
                self.push(TailOp::Binary { op, a, b }, info, &out, vals);
                Ok(())
            }
            "Sqrt" | "Sigmoid" | "Softplus" | "Reciprocal" | "Relu" | "Exp" => {
                node.input_count(1, 1)?;
                node.only_attributes(&[])?;
                let src = self.slot_of(node, vals, &node.inputs[0])?;
                let op = match node.op.as_str() {
                    "Sqrt" => Unary::Sqrt,
                    "Sigmoid" => Unary::Sigmoid,
                    "Softplus" => Unary::Softplus,
                    "Reciprocal" => Unary::Reciprocal,
                    "Relu" => Unary::Relu,
                    _ => Unary::Exp,
                };
                let info = self.slots[src];
                self.push(TailOp::Unary { op, src }, info, &out, vals);
                Ok(())
            }
            "Clip" => {
                node.input_count(1, 3)?;
                node.only_attributes(&[])?;
                let src = self.slot_of(node, vals, &node.inputs[0])?;
                let lo = Self::const_scalar(graph, node, 1)?.unwrap_or(f32::NEG_INFINITY);
                let hi = Self::const_scalar(graph, node, 2)?.unwrap_or(f32::INFINITY);
                let info = self.slots[src];
                self.push(TailOp::Clip { src, lo, hi }, info, &out, vals);
                Ok(())
            }
            "ReduceSum" => {
                node.input_count(1, 2)?;
                node.only_attributes(&["keepdims", "noop_with_empty_axes"])?;
                let src = self.slot_of(node, vals, &node.inputs[0])?;
                let axes = Self::axis1(graph, node, 1)?;
                if self.slots[src].rank != 2 || !matches!(axes.as_deref(), Some([1]) | Some([-1])) {
                    return Err(node.refuse("only a sum over the columns of a matrix is supported"));
                }
                let rank = if node.int("keepdims", 1) != 0 { 2 } else { 1 };
                self.push(TailOp::ReduceSum { src }, SlotInfo { cols: 1, rank }, &out, vals);
                Ok(())
            }
            other => Err(node.refuse(format!(
                "operator {other} is outside the native MLP subset (Gemm, MatMul, Add, Sub, Mul, \
                 Div, Relu, Slice, Gather, ReduceSum, Sqrt, Sigmoid, Softplus, Reciprocal, Exp, Clip)"
            ))),
        }
    }

    /// Folds `Relu` or `Add` of a constant bias into the dense layer it reads, if it does.
    fn fuse_into_layer(
        &mut self,
        graph: &Graph,
        node: &Node,
        readers: &HashMap<String, usize>,
        vals: &mut HashMap<String, Val>,
    ) -> Result<bool, Unsupported> {
        let layer_input = node.inputs.iter().position(|i| {
            matches!(vals.get(i), Some(Val::Layer(l)) if *l + 1 == self.layers.len())
                && readers.get(i).copied() == Some(1)
        });
        let Some(pos) = layer_input else {
            return Ok(false);
        };
        let last = self.layers.len() - 1;
        if node.op == "Relu" {
            node.input_count(1, 1)?;
            node.only_attributes(&[])?;
            self.layers[last].relu = true;
        } else {
            node.input_count(2, 2)?;
            node.only_attributes(&[])?;
            let other = &node.inputs[1 - pos];
            let Some(c) = graph.constant(other) else {
                return Ok(false);
            };
            let l = &mut self.layers[last];
            let v = c.f32s();
            if l.relu || !(v.len() == l.n || v.len() == 1) || c.shape.len() > 2 {
                return Ok(false);
            }
            for j in 0..l.n {
                l.b[j] += if v.len() == 1 { v[0] } else { v[j] };
            }
        }
        vals.insert(node.outputs[0].clone(), Val::Layer(last));
        Ok(true)
    }
}

/// Per-thread scratch of [`run_block`].
#[derive(Default)]
pub struct Scratch {
    act: [Vec<f32>; 2],
    slots: Vec<Vec<f32>>,
}

impl MlpPlan {
    /// Runs `rows` rows of `features` (`[rows, in_dim]`), writing each output's rows into
    /// `outs[i]` (`rows × cols`).
    pub fn run_block(
        &self,
        features: &[f32],
        rows: usize,
        s: &mut Scratch,
        outs: &mut [&mut [f32]],
    ) {
        let mut cur = 0;
        for (i, l) in self.layers.iter().enumerate() {
            let dst = 1 - cur;
            let mut out = std::mem::take(&mut s.act[dst]);
            out.clear();
            for _ in 0..rows {
                out.extend_from_slice(&l.b);
            }
            let (a, lda) = if i == 0 {
                (features, self.in_dim)
            } else {
                (&s.act[cur][..], self.layers[i - 1].np)
            };
            assert!(a.len() >= rows * lda && lda >= l.k, "MLP block input");
            // SAFETY: A is `rows × k` with row stride `lda` inside `a`, B is `k × np` packed,
            // C is `rows × np` (filled with the bias above, accumulated with beta = 1).
            unsafe {
                matrixmultiply::sgemm(
                    rows,
                    l.k,
                    l.np,
                    1.0,
                    a.as_ptr(),
                    lda as isize,
                    1,
                    l.w.as_ptr(),
                    l.np as isize,
                    1,
                    1.0,
                    out.as_mut_ptr(),
                    l.np as isize,
                    1,
                );
            }
            if l.relu {
                out.iter_mut().for_each(|v| *v = v.max(0.0));
            }
            s.act[dst] = out;
            cur = dst;
        }
        let last = self.layers.last().expect("at least one layer");
        s.slots.resize_with(self.slots.len(), Vec::new);
        // Slot 0: the last layer's real columns.
        let raw = &mut s.slots[0];
        raw.clear();
        for r in 0..rows {
            raw.extend_from_slice(&s.act[cur][r * last.np..r * last.np + last.n]);
        }
        for (i, op) in self.tail.iter().enumerate() {
            let info = self.slots[i + 1];
            let mut dst = std::mem::take(&mut s.slots[i + 1]);
            dst.clear();
            dst.resize(rows * info.cols, 0.0);
            self.tail_op(op, info, &s.slots, rows, &mut dst);
            s.slots[i + 1] = dst;
        }
        for (o, &slot) in outs.iter_mut().zip(&self.outputs) {
            o.copy_from_slice(&s.slots[slot][..o.len()]);
        }
    }

    fn tail_op(
        &self,
        op: &TailOp,
        info: SlotInfo,
        slots: &[Vec<f32>],
        rows: usize,
        dst: &mut [f32],
    ) {
        let cols = info.cols;
        let at = |o: &Operand, r: usize, c: usize| -> f32 {
            match o {
                Operand::Scalar(v) => *v,
                Operand::Row(v) => v[if v.len() == 1 { 0 } else { c }],
                Operand::Slot(s) => {
                    let w = self.slots[*s].cols;
                    slots[*s][r * w + if w == 1 { 0 } else { c }]
                }
            }
        };
        match op {
            TailOp::Take { src, cols: take } => {
                let w = self.slots[*src].cols;
                for r in 0..rows {
                    for (j, &c) in take.iter().enumerate() {
                        dst[r * cols + j] = slots[*src][r * w + c];
                    }
                }
            }
            TailOp::Binary { op, a, b } => {
                for r in 0..rows {
                    for c in 0..cols {
                        let (x, y) = (at(a, r, c), at(b, r, c));
                        dst[r * cols + c] = match op {
                            Binary::Add => x + y,
                            Binary::Sub => x - y,
                            Binary::Mul => x * y,
                            Binary::Div => x / y,
                        };
                    }
                }
            }
            TailOp::Unary { op, src } => {
                for (d, &x) in dst.iter_mut().zip(&slots[*src]) {
                    *d = match op {
                        Unary::Sqrt => x.sqrt(),
                        Unary::Sigmoid => 1.0 / (1.0 + (-x).exp()),
                        Unary::Softplus => {
                            if x > 0.0 {
                                x + (-x).exp().ln_1p()
                            } else {
                                x.exp().ln_1p()
                            }
                        }
                        Unary::Reciprocal => 1.0 / x,
                        Unary::Relu => x.max(0.0),
                        Unary::Exp => x.exp(),
                    };
                }
            }
            TailOp::Clip { src, lo, hi } => {
                for (d, &x) in dst.iter_mut().zip(&slots[*src]) {
                    *d = x.max(*lo).min(*hi);
                }
            }
            TailOp::ReduceSum { src } => {
                let w = self.slots[*src].cols;
                for r in 0..rows {
                    dst[r] = slots[*src][r * w..(r + 1) * w].iter().sum();
                }
            }
        }
    }

    /// Output `i`'s columns.
    pub fn output_cols(&self, i: usize) -> usize {
        self.slots[self.outputs[i]].cols
    }

    /// Input width.
    pub fn in_dim(&self) -> usize {
        self.in_dim
    }
}
