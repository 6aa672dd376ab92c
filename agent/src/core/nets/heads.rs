//! C per-objective critic heads run as one batched matmul per layer (appendix A: "a
//! separate critic is trained for each objective"), with the member axis of
//! population training in front (see `mlp/mod.rs`). Heads of ε-conditioned critics
//! may carry the preference features to every layer after their first
//! (`network.critic_preference`), as `LayerNormMlp::carrying` does.
//!
//! Shape legend: P members, R rows, C heads, F carried features.

use super::activation::elu_;
use super::mlp::{Members, append_carried};
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
    /// Carried feature columns appended to every layer's input after the first.
    carry: i64,
}

impl HeadStack {
    /// `sizes[0]` is the input width, the rest the hidden sizes; parameters under
    /// `p/linear_i`.
    pub fn new(p: &nn::Path, heads: i64, sizes: &[i64]) -> Self {
        Self::with_members(p, heads, sizes, 0, Members::ONE)
    }

    /// As `new`, for `members` networks whose layers after the first also read
    /// `carry` carried columns (`sizes[0]` includes them where the input has them).
    pub fn with_members(
        p: &nn::Path,
        heads: i64,
        sizes: &[i64],
        carry: i64,
        members: Members,
    ) -> Self {
        let mut sizes = sizes.to_vec();
        sizes.push(1);
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(i, w)| {
                let path = p / format!("linear_{i}");
                let input = if i == 0 { w[0] } else { w[0] + carry };
                StackedDense::new(&path, heads, input, w[1], members)
            })
            .collect();
        Self {
            layers,
            members,
            carry,
        }
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
            carry: self.carry,
        }
    }

    /// `x [.., 1, R, in]`, `carried [.., 1, R, F] -> [.., C, R]`: the layers, ELU
    /// between them, the carried columns appended to every input after the first.
    fn run(&self, mut x: Tensor, carried: Option<&Tensor>) -> Tensor {
        assert_eq!(
            carried.map_or(0, |c| c.size()[c.dim() - 1]),
            self.carry,
            "carried columns"
        );
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            if i > 0 {
                x = append_carried(x, carried);
            }
            x = layer.forward(&x);
            if i < last {
                // In place: Linear's backward does not need its output.
                elu_(&mut x);
            }
        }
        x.squeeze_dim(-1)
    }

    /// `carried` holds the `carry` carried columns of each row (none when 0).
    /// # Shapes
    /// `h [R, in]`, `carried [R, F] -> [R, C]` (one member).
    pub fn forward(&self, h: &Tensor, carried: Option<&Tensor>) -> Tensor {
        let carried = carried.map(|c| c.unsqueeze(0));
        self.run(h.unsqueeze(0), carried.as_ref()).transpose(0, 1)
    }

    /// # Shapes
    /// `h [P, R, in]`, `carried [P, R, F] -> [P, R, C]`.
    pub fn forward_members(&self, h: &Tensor, carried: Option<&Tensor>) -> Tensor {
        if !self.members.stacked() {
            let carried = carried.map(|c| c.squeeze_dim(0));
            return self
                .forward(&h.squeeze_dim(0), carried.as_ref())
                .unsqueeze(0);
        }
        let carried = carried.map(|c| c.unsqueeze(1));
        self.run(h.unsqueeze(1), carried.as_ref()).transpose(1, 2)
    }
}
