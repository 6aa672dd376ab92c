//! The layers every network is built from: Linear -> LayerNorm -> tanh, then Linear
//! -> ELU per further hidden layer (Table 2 "layer norm on first layer", "tanh on
//! output of layer norm", "activation ELU"). The critics' heads are in `heads.rs`.
//!
//! Weights use PyTorch's `nn.Linear` initialisation, uniform(-1/sqrt(fan_in), 1/sqrt(fan_in))
//! for weight and bias, so the PyTorch reference in `benches/` builds the same networks.
//!
//! Population training (docs/design.md, "Populations") gives every layer a member axis:
//! P members' parameters stacked along a leading axis, so that one batched matmul
//! runs a layer of all P networks. `forward_members` takes and returns member-first
//! tensors `[P, R, ..]`. A layer of one member keeps today's unstacked shapes and
//! names (checkpoints, snapshots and the Python loader read them) and runs the same
//! kernels as `forward`, so a population of one computes a single network's numbers
//! bit for bit.
//!
//! Shape legend: P members, R rows (states or state-action pairs).

use super::activation::{elu_, tanh_};
use tch::{Tensor, nn};

/// How many members' parameters a layer holds: one with today's shapes, or P >= 2
/// stacked along a leading member axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Members(i64);

impl Members {
    /// One member: unstacked parameters.
    pub const ONE: Members = Members(1);

    /// `count` members; `None` for fewer than one.
    pub fn new(count: i64) -> Option<Self> {
        (count >= 1).then_some(Members(count))
    }

    /// P.
    pub fn count(self) -> i64 {
        self.0
    }

    pub(crate) fn stacked(self) -> bool {
        self.0 > 1
    }

    /// Members `start..start + len` of a stacked parameter `t` as a view: stacked
    /// (`len` >= 2) or one member's unstacked tensor (`len` = 1); `t` itself when
    /// this is one member.
    pub(crate) fn view(self, t: &Tensor, start: i64, len: i64) -> Tensor {
        match (self.stacked(), len) {
            (false, _) => t.shallow_clone(),
            (true, 1) => t.get(start),
            (true, _) => t.narrow(0, start, len),
        }
    }

    /// The member count of a view of `len` members of this layer.
    pub(crate) fn narrowed(self, len: i64) -> Members {
        if self.stacked() { Members(len) } else { self }
    }

    /// A parameter's shape: `dims`, behind the member axis when stacked.
    pub(crate) fn shape(self, dims: &[i64]) -> Vec<i64> {
        if self.stacked() {
            [&[self.0][..], dims].concat()
        } else {
            dims.to_vec()
        }
    }
}

/// A dense layer `y = x W^T + b` with weight `[out, in]` (`[P, out, in]` stacked).
#[derive(Debug)]
pub struct Dense {
    /// Weight `[out, in]`, or `[P, out, in]`.
    pub weight: Tensor,
    /// Bias `[out]` (`[P, out]`), absent for the action half of a split first layer.
    pub bias: Option<Tensor>,
    members: Members,
}

impl Dense {
    /// Creates `weight` (and `bias`) under `p`, initialised with bound 1/sqrt(fan_in).
    /// `fan_in` may exceed `input` when this layer is part of a split layer.
    pub fn new(p: &nn::Path, input: i64, output: i64, fan_in: i64, bias: bool) -> Self {
        Self::with_members(p, input, output, fan_in, bias, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(
        p: &nn::Path,
        input: i64,
        output: i64,
        fan_in: i64,
        bias: bool,
        members: Members,
    ) -> Self {
        let bound = 1.0 / (fan_in as f64).sqrt();
        let init = nn::Init::Uniform {
            lo: -bound,
            up: bound,
        };
        let weight = p.var("weight", &members.shape(&[output, input]), init);
        let bias = bias.then(|| p.var("bias", &members.shape(&[output]), init));
        Self {
            weight,
            bias,
            members,
        }
    }

    /// # Shapes
    /// `[.., in] -> [.., out]` (one member).
    pub fn forward(&self, x: &Tensor) -> Tensor {
        x.linear(&self.weight, self.bias.as_ref())
    }

    /// Members `start..start + len` as a layer of their own (views of the parameters,
    /// for untracked passes run a few members at a time).
    pub fn narrow_members(&self, start: i64, len: i64) -> Self {
        Self {
            weight: self.members.view(&self.weight, start, len),
            bias: self.bias.as_ref().map(|b| self.members.view(b, start, len)),
            members: self.members.narrowed(len),
        }
    }

    /// # Shapes
    /// `[P, R, in] -> [P, R, out]`.
    pub fn forward_members(&self, x: &Tensor) -> Tensor {
        if !self.members.stacked() {
            return self.forward(x);
        }
        let weight_t = self.weight.transpose(1, 2);
        match &self.bias {
            Some(b) => b.unsqueeze(1).baddbmm(x, &weight_t, 1.0, 1.0),
            None => x.bmm(&weight_t),
        }
    }
}

/// LayerNorm with learned scale and shift over the last dimension (eps 1e-5).
#[derive(Debug)]
pub struct Norm {
    weight: Tensor,
    bias: Tensor,
    dim: i64,
    members: Members,
}

const LAYER_NORM_EPS: f64 = 1e-5;

impl Norm {
    /// Creates `weight` (ones) and `bias` (zeros) of width `dim` under `p`.
    pub fn new(p: &nn::Path, dim: i64) -> Self {
        Self::with_members(p, dim, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(p: &nn::Path, dim: i64, members: Members) -> Self {
        Self {
            weight: p.var("weight", &members.shape(&[dim]), nn::Init::Const(1.0)),
            bias: p.var("bias", &members.shape(&[dim]), nn::Init::Const(0.0)),
            dim,
            members,
        }
    }

    /// Members `start..start + len` (views), as `Dense::narrow_members`.
    pub fn narrow_members(&self, start: i64, len: i64) -> Self {
        Self {
            weight: self.members.view(&self.weight, start, len),
            bias: self.members.view(&self.bias, start, len),
            dim: self.dim,
            members: self.members.narrowed(len),
        }
    }

    /// LayerNorm then tanh. # Shapes `[.., dim] -> [.., dim]` (one member).
    pub fn forward_tanh(&self, x: &Tensor) -> Tensor {
        // In place: LayerNorm's backward needs its input, not its output.
        let mut y = x.layer_norm(
            [self.dim],
            Some(&self.weight),
            Some(&self.bias),
            LAYER_NORM_EPS,
            true,
        );
        tanh_(&mut y);
        y
    }

    /// # Shapes
    /// `[P, R, dim] -> [P, R, dim]`.
    pub fn forward_tanh_members(&self, x: &Tensor) -> Tensor {
        if !self.members.stacked() {
            return self.forward_tanh(x);
        }
        // libtorch's fused affine takes one [dim] scale; members scale separately.
        let normed = x.layer_norm([self.dim], None::<Tensor>, None, LAYER_NORM_EPS, true);
        let mut y = self
            .bias
            .unsqueeze(1)
            .addcmul(&normed, &self.weight.unsqueeze(1));
        tanh_(&mut y);
        y
    }
}

/// Linear -> LayerNorm -> tanh, then Linear -> ELU for each further hidden size.
///
/// A network that *carries* its last `carry` input columns (an ε-conditioned policy's
/// preference features, `NetworkConfig::policy_preference`) appends them again to the
/// input of every further layer and to its output, so that they reach each layer
/// directly rather than only through the first layer's LayerNorm, where the
/// observation's other columns share one normalisation with them.
#[derive(Debug)]
pub struct LayerNormMlp {
    first: Dense,
    norm: Norm,
    hidden: Vec<Dense>,
    /// The carried input columns: `input - carry..input` (`carry` 0: none).
    carried: CarriedColumns,
    output_dim: i64,
}

/// Which trailing input columns a `LayerNormMlp` appends to every later layer's input.
#[derive(Debug, Clone, Copy)]
struct CarriedColumns {
    start: i64,
    len: i64,
}

impl CarriedColumns {
    /// `h` with the carried columns of the network's input `x` appended (`h` itself
    /// when nothing is carried). # Shapes `h [.., H]`, `x [.., input] -> [.., H + len]`.
    fn append(self, h: Tensor, x: &Tensor) -> Tensor {
        if self.len == 0 {
            return h;
        }
        append_carried(h, Some(&x.narrow(-1, self.start, self.len)))
    }
}

/// `h` with `carried` appended along the last axis, broadcast over `h`'s leading axes
/// (`h` itself when nothing is carried).
/// # Shapes
/// `h [.., R, H]`, `carried [.., R, F]` (leading axes of size 1 or `h`'s) `-> [.., R, H + F]`.
pub(crate) fn append_carried(h: Tensor, carried: Option<&Tensor>) -> Tensor {
    let Some(carried) = carried else {
        return h;
    };
    let mut shape = h.size();
    if let Some(last) = shape.last_mut() {
        *last = carried.size()[carried.dim() - 1];
    }
    Tensor::cat(&[h, carried.expand(&shape, false)], -1)
}

impl LayerNormMlp {
    /// `layers` are the hidden sizes (non-empty); parameters live under `p`.
    pub fn new(p: &nn::Path, input: i64, layers: &[i64]) -> Self {
        Self::with_members(p, input, layers, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(p: &nn::Path, input: i64, layers: &[i64], members: Members) -> Self {
        Self::carrying(p, input, layers, 0, members)
    }

    /// As `with_members`, appending the last `carry` input columns to the input of
    /// every layer after the first and to the output (`carry` <= `input`).
    pub fn carrying(
        p: &nn::Path,
        input: i64,
        layers: &[i64],
        carry: i64,
        members: Members,
    ) -> Self {
        assert!(
            (0..=input).contains(&carry),
            "carry {carry} of {input} input columns"
        );
        let first = Dense::with_members(&(p / "linear_0"), input, layers[0], input, true, members);
        let norm = Norm::with_members(&(p / "layer_norm"), layers[0], members);
        let hidden = layers
            .windows(2)
            .enumerate()
            .map(|(i, w)| {
                let path = p / format!("linear_{}", i + 1);
                let fan_in = w[0] + carry;
                Dense::with_members(&path, fan_in, w[1], fan_in, true, members)
            })
            .collect();
        Self {
            first,
            norm,
            hidden,
            carried: CarriedColumns {
                start: input - carry,
                len: carry,
            },
            output_dim: layers.last().unwrap_or(&input) + carry,
        }
    }

    /// Members `start..start + len` (views), as `Dense::narrow_members`.
    pub fn narrow_members(&self, start: i64, len: i64) -> Self {
        Self {
            first: self.first.narrow_members(start, len),
            norm: self.norm.narrow_members(start, len),
            hidden: self
                .hidden
                .iter()
                .map(|d| d.narrow_members(start, len))
                .collect(),
            carried: self.carried,
            output_dim: self.output_dim,
        }
    }

    /// Width of the output: the last hidden layer's, and the carried columns.
    pub fn output_dim(&self) -> i64 {
        self.output_dim
    }

    /// # Shapes
    /// `[.., input] -> [.., output_dim]` (one member).
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let mut h = self.norm.forward_tanh(&self.first.forward(x));
        for layer in &self.hidden {
            h = layer.forward(&self.carried.append(h, x));
            // In place: Linear's backward does not need its output.
            elu_(&mut h);
        }
        self.carried.append(h, x)
    }

    /// # Shapes
    /// `[P, R, input] -> [P, R, output_dim]`.
    pub fn forward_members(&self, x: &Tensor) -> Tensor {
        let mut h = self
            .norm
            .forward_tanh_members(&self.first.forward_members(x));
        for layer in &self.hidden {
            h = layer.forward_members(&self.carried.append(h, x));
            elu_(&mut h);
        }
        self.carried.append(h, x)
    }
}

#[cfg(test)]
mod tests;
