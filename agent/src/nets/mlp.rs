//! The shared torso of every network: Linear -> LayerNorm -> tanh, then Linear -> ELU
//! per further hidden layer (Table 2 "layer norm on first layer", "tanh on output of
//! layer norm", "activation ELU").
//!
//! Weights use PyTorch's `nn.Linear` initialisation, uniform(-1/sqrt(fan_in), 1/sqrt(fan_in))
//! for weight and bias, so the PyTorch reference in `benches/` builds the same networks.
//!
//! The activations run in place. Where no gradient is tracked (target networks, actors)
//! they are computed from cheaper kernels: libtorch 2.13's AVX-512 CPU kernels for ELU
//! (via expm1) and tanh take 6.7 and 3 ns per element on the development machine, exp
//! and sigmoid 1 and 0.6, and the target critic's M samples per state make these
//! activations a third of a learner step. The identities used are exact;
//! only the rounding differs (by at most a few 1e-7).

use tch::{Tensor, nn};

/// A dense layer `y = x W^T + b` with weight `[out, in]`.
#[derive(Debug)]
pub struct Dense {
    /// Weight `[out, in]`.
    pub weight: Tensor,
    /// Bias `[out]`, absent for the action half of a split first layer.
    pub bias: Option<Tensor>,
}

impl Dense {
    /// Creates `weight` (and `bias`) under `p`, initialised with bound 1/sqrt(fan_in).
    /// `fan_in` may exceed `input` when this layer is part of a split layer.
    pub fn new(p: &nn::Path, input: i64, output: i64, fan_in: i64, bias: bool) -> Self {
        let bound = 1.0 / (fan_in as f64).sqrt();
        let init = nn::Init::Uniform {
            lo: -bound,
            up: bound,
        };
        let weight = p.var("weight", &[output, input], init);
        let bias = bias.then(|| p.var("bias", &[output], init));
        Self { weight, bias }
    }

    /// # Shapes
    /// `[.., in] -> [.., out]`.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        x.linear(&self.weight, self.bias.as_ref())
    }
}

/// ELU in place. Untracked: `elu(x) = max(x, exp(min(x, 0)) - 1)` (for x <= 0,
/// exp(x) - 1 >= x; for x > 0 the second term is 0 < x).
pub(crate) fn elu_(x: &mut Tensor) {
    if x.requires_grad() {
        // ELU's backward uses its result, so in place is autograd-safe.
        let _ = x.elu_();
        return;
    }
    let mut negative_part = x.clamp_max(0.0);
    let _ = negative_part.exp_();
    let _ = negative_part.g_sub_scalar_(1.0);
    let _ = x.maximum_out(x, &negative_part);
}

/// tanh in place. Untracked: `tanh(x) = 2 sigmoid(2x) - 1`.
pub(crate) fn tanh_(x: &mut Tensor) {
    if x.requires_grad() {
        // tanh's backward uses its result, so in place is autograd-safe.
        let _ = x.tanh_();
        return;
    }
    let _ = x.g_mul_scalar_(2.0);
    let _ = x.sigmoid_();
    let _ = x.g_mul_scalar_(2.0);
    let _ = x.g_sub_scalar_(1.0);
}

/// LayerNorm with learned scale and shift over the last dimension (eps 1e-5).
#[derive(Debug)]
pub struct Norm {
    inner: nn::LayerNorm,
}

impl Norm {
    /// Creates `weight` (ones) and `bias` (zeros) of width `dim` under `p`.
    pub fn new(p: &nn::Path, dim: i64) -> Self {
        Self {
            inner: nn::layer_norm(p, vec![dim], Default::default()),
        }
    }

    /// LayerNorm then tanh. # Shapes `[.., dim] -> [.., dim]`.
    pub fn forward_tanh(&self, x: &Tensor) -> Tensor {
        // In place: LayerNorm's backward needs its input, not its output.
        let mut y = nn::Module::forward(&self.inner, x);
        tanh_(&mut y);
        y
    }
}

/// Linear -> LayerNorm -> tanh, then Linear -> ELU for each further hidden size.
#[derive(Debug)]
pub struct LayerNormMlp {
    first: Dense,
    norm: Norm,
    hidden: Vec<Dense>,
    output_dim: i64,
}

impl LayerNormMlp {
    /// `layers` are the hidden sizes (non-empty); parameters live under `p`.
    pub fn new(p: &nn::Path, input: i64, layers: &[i64]) -> Self {
        let first = Dense::new(&(p / "linear_0"), input, layers[0], input, true);
        let norm = Norm::new(&(p / "layer_norm"), layers[0]);
        let hidden = layers
            .windows(2)
            .enumerate()
            .map(|(i, w)| Dense::new(&(p / format!("linear_{}", i + 1)), w[0], w[1], w[0], true))
            .collect();
        Self {
            first,
            norm,
            hidden,
            output_dim: *layers.last().unwrap_or(&input),
        }
    }

    /// Width of the last hidden layer.
    pub fn output_dim(&self) -> i64 {
        self.output_dim
    }

    /// # Shapes
    /// `[.., input] -> [.., layers.last()]`.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let mut h = self.norm.forward_tanh(&self.first.forward(x));
        for layer in &self.hidden {
            h = layer.forward(&h);
            // In place: Linear's backward does not need its output.
            elu_(&mut h);
        }
        h
    }
}

/// One layer of C independent heads at once: weight `[C, in, out]`, bias `[C, 1, out]`.
#[derive(Debug)]
struct StackedDense {
    weight: Tensor,
    bias: Tensor,
}

impl StackedDense {
    fn new(p: &nn::Path, heads: i64, input: i64, output: i64) -> Self {
        let bound = 1.0 / (input as f64).sqrt();
        let init = nn::Init::Uniform {
            lo: -bound,
            up: bound,
        };
        Self {
            weight: p.var("weight", &[heads, input, output], init),
            bias: p.var("bias", &[heads, 1, output], init),
        }
    }

    /// `[C or 1, P, in] -> [C, P, out]`.
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
}

impl HeadStack {
    /// `sizes[0]` is the input width, the rest the hidden sizes; parameters under
    /// `p/linear_i`.
    pub fn new(p: &nn::Path, heads: i64, sizes: &[i64]) -> Self {
        let mut sizes = sizes.to_vec();
        sizes.push(1);
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(i, w)| StackedDense::new(&(p / format!("linear_{i}")), heads, w[0], w[1]))
            .collect();
        Self { layers }
    }

    /// # Shapes
    /// `[P, in] -> [P, C]`.
    pub fn forward(&self, h: &Tensor) -> Tensor {
        let mut x = h.unsqueeze(0);
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            x = layer.forward(&x);
            if i < last {
                // In place: Linear's backward does not need its output.
                elu_(&mut x);
            }
        }
        x.squeeze_dim(-1).transpose(0, 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn untracked_activations_match_libtorch() {
        let x = Tensor::linspace(-12.0, 12.0, 4801, (Kind::Float, Device::Cpu));
        for (name, fast, reference) in [
            ("elu", elu_ as fn(&mut Tensor), x.elu()),
            ("tanh", tanh_ as fn(&mut Tensor), x.tanh()),
        ] {
            let mut y = x.copy();
            fast(&mut y);
            let err = (&y - &reference).abs().max().double_value(&[]);
            assert!(err < 5e-7, "{name}: max error {err}");
        }
    }

    #[test]
    fn shapes_and_first_layer_is_bounded() {
        let vs = nn::VarStore::new(Device::Cpu);
        let mlp = LayerNormMlp::new(&(vs.root() / "torso"), 5, &[8]);
        let y = mlp.forward(&(Tensor::randn([3, 5], (Kind::Float, Device::Cpu)) * 100.0));
        assert_eq!(y.size(), vec![3, 8]);
        // With one layer the output is tanh(LayerNorm(.)), so strictly inside (-1, 1).
        assert!(y.abs().max().double_value(&[]) < 1.0);
        let mlp = LayerNormMlp::new(&(vs.root() / "deep"), 5, &[8, 4, 2]);
        assert_eq!(
            mlp.forward(&Tensor::zeros([7, 5], (Kind::Float, Device::Cpu)))
                .size(),
            vec![7, 2]
        );
        assert_eq!(mlp.output_dim(), 2);
    }
}
