//! The shared torso of every network: Linear -> LayerNorm -> tanh, then Linear -> ELU
//! per further hidden layer (Table 2 "layer norm on first layer", "tanh on output of
//! layer norm", "activation ELU").
//!
//! Weights use PyTorch's `nn.Linear` initialisation, uniform(-1/sqrt(fan_in), 1/sqrt(fan_in))
//! for weight and bias, so the PyTorch reference in `benches/` builds the same networks.

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
        // In place: LayerNorm's backward needs its input, not its output; tanh's uses
        // its result.
        let mut y = nn::Module::forward(&self.inner, x);
        let _ = y.tanh_();
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
            // In place: ELU's backward uses its result, Linear's does not need it.
            let _ = h.elu_();
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
        let init = nn::Init::Uniform { lo: -bound, up: bound };
        Self { weight: p.var("weight", &[heads, input, output], init), bias: p.var("bias", &[heads, 1, output], init) }
    }

    /// `[C or 1, P, in] -> [C, P, out]`.
    fn forward(&self, x: &Tensor) -> Tensor {
        x.matmul(&self.weight) + &self.bias
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
                // In place: ELU's backward uses its result, Linear's does not need it.
                let _ = x.elu_();
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
