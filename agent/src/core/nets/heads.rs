//! C per-objective critic heads run as one batched matmul per layer (appendix A: "a
//! separate critic is trained for each objective"), with the member axis of
//! population training in front (see `mlp/mod.rs`).
//!
//! Shape legend: P members, R rows, C heads.

use super::activation::elu_;
use super::mlp::Members;
use tch::{Tensor, nn};

/// One layer of C independent heads at once: weight `[C, in, out]`, bias `[C, 1, out]`
/// (`[P, C, in, out]` and `[P, C, 1, out]` stacked).
#[derive(Debug)]
struct StackedDense {
    weight: Tensor,
    bias: Tensor,
}

impl StackedDense {
    fn narrow_members(&self, members: Members, start: i64, len: i64) -> Self {
        Self {
            weight: members.view(&self.weight, start, len),
            bias: members.view(&self.bias, start, len),
        }
    }

    fn new(p: &nn::Path, heads: i64, input: i64, output: i64, members: Members) -> Self {
        let bound = 1.0 / (input as f64).sqrt();
        let init = nn::Init::Uniform {
            lo: -bound,
            up: bound,
        };
        Self {
            weight: p.var("weight", &members.shape(&[heads, input, output]), init),
            bias: p.var("bias", &members.shape(&[heads, 1, output]), init),
        }
    }

    /// `[.., C or 1, R, in] -> [.., C, R, out]`, the leading axes those of the weight.
    fn forward(&self, x: &Tensor) -> Tensor {
        // The bias is added in place: the product is a fresh tensor, and an add's
        // backward needs neither operand.
        let mut y = x.matmul(&self.weight);
        let _ = y.g_add_(&self.bias);
        y
    }
}

/// C per-objective heads, each Linear -> ELU per hidden size and a final Linear to one
/// value, run as one batched matmul per layer (so all objectives cost one pass).
#[derive(Debug)]
pub struct HeadStack {
    layers: Vec<StackedDense>,
    members: Members,
}

impl HeadStack {
    /// `sizes[0]` is the input width, the rest the hidden sizes; parameters under
    /// `p/linear_i`.
    pub fn new(p: &nn::Path, heads: i64, sizes: &[i64]) -> Self {
        Self::with_members(p, heads, sizes, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(p: &nn::Path, heads: i64, sizes: &[i64], members: Members) -> Self {
        let mut sizes = sizes.to_vec();
        sizes.push(1);
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(i, w)| {
                let path = p / format!("linear_{i}");
                StackedDense::new(&path, heads, w[0], w[1], members)
            })
            .collect();
        Self { layers, members }
    }

    /// Members `start..start + len` (views), as `Dense::narrow_members`.
    pub fn narrow_members(&self, start: i64, len: i64) -> Self {
        Self {
            layers: self
                .layers
                .iter()
                .map(|l| l.narrow_members(self.members, start, len))
                .collect(),
            members: self.members.narrowed(len),
        }
    }

    /// `x [.., 1, R, in] -> [.., C, R]`: the layers, ELU between them.
    fn run(&self, mut x: Tensor) -> Tensor {
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            x = layer.forward(&x);
            if i < last {
                // In place: Linear's backward does not need its output.
                elu_(&mut x);
            }
        }
        x.squeeze_dim(-1)
    }

    /// # Shapes
    /// `[R, in] -> [R, C]` (one member).
    pub fn forward(&self, h: &Tensor) -> Tensor {
        self.run(h.unsqueeze(0)).transpose(0, 1)
    }

    /// # Shapes
    /// `[P, R, in] -> [P, R, C]`.
    pub fn forward_members(&self, h: &Tensor) -> Tensor {
        if !self.members.stacked() {
            return self.forward(&h.squeeze_dim(0)).unsqueeze(0);
        }
        self.run(h.unsqueeze(1)).transpose(1, 2)
    }
}
