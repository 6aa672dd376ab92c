//! Unit tests of the layers: members against single networks, carried columns, shapes.

use super::super::heads::HeadStack;
use super::*;
use crate::core::random::{Purpose, StreamKey};
use tch::{Device, Kind};

const P: i64 = 3;

/// Test inputs from a keyed stream, not libtorch's shared generator.
fn randn(shape: &[i64]) -> Tensor {
    StreamKey::new(0, Purpose::LearnerActing, 0)
        .at(shape.iter().product::<i64>() as u64)
        .normal(shape, Device::Cpu)
}

/// Member `p` of every stacked variable of `population`, copied from `single`'s
/// variable of the same name.
fn load_member(population: &nn::VarStore, p: i64, single: &nn::VarStore) {
    let stacked = population.variables();
    for (name, value) in single.variables() {
        tch::no_grad(|| stacked[&name].get(p).copy_(&value));
    }
}

/// A network type as the member tests drive it.
trait Net {
    fn build(p: &nn::Path, members: Members) -> Self;
    fn forward(&self, x: &Tensor) -> Tensor;
    fn forward_members(&self, x: &Tensor) -> Tensor;
}

impl Net for LayerNormMlp {
    fn build(p: &nn::Path, members: Members) -> Self {
        LayerNormMlp::with_members(p, 5, &[8, 6], members)
    }
    fn forward(&self, x: &Tensor) -> Tensor {
        LayerNormMlp::forward(self, x)
    }
    fn forward_members(&self, x: &Tensor) -> Tensor {
        LayerNormMlp::forward_members(self, x)
    }
}

impl Net for HeadStack {
    fn build(p: &nn::Path, members: Members) -> Self {
        HeadStack::with_members(p, 2, &[5, 6], 0, members)
    }
    fn forward(&self, x: &Tensor) -> Tensor {
        HeadStack::forward(self, x, None)
    }
    fn forward_members(&self, x: &Tensor) -> Tensor {
        HeadStack::forward_members(self, x, None)
    }
}

/// A population of one runs the single network's kernels on the same shapes.
fn one_member_is_bit_for_bit<N: Net>() {
    let vs = nn::VarStore::new(Device::Cpu);
    let net = N::build(&vs.root(), Members::ONE);
    let x = randn(&[7, 5]);
    let single = net.forward(&x);
    assert!(
        net.forward_members(&x.unsqueeze(0))
            .squeeze_dim(0)
            .equal(&single)
    );
}

/// Member p of a stacked network computes what a single network with p's
/// parameters computes, and gets exactly that network's gradient from the
/// members' summed loss.
fn stacked_members_are_their_single_networks<N: Net>() {
    let singles: Vec<(nn::VarStore, N)> = (0..P)
        .map(|_| {
            let vs = nn::VarStore::new(Device::Cpu);
            let net = N::build(&vs.root(), Members::ONE);
            (vs, net)
        })
        .collect();
    let population_vs = nn::VarStore::new(Device::Cpu);
    let population = N::build(&population_vs.root(), Members::new(P).unwrap());
    for (p, (vs, _)) in singles.iter().enumerate() {
        load_member(&population_vs, p as i64, vs);
    }
    let x = randn(&[P, 7, 5]);
    let out = population.forward_members(&x);
    out.square().sum(Kind::Float).backward();
    let stacked = population_vs.variables();
    for (p, (vs, net)) in singles.iter().enumerate() {
        let single = net.forward(&x.get(p as i64));
        // Batched and single GEMMs may round differently; a wrong member or a
        // missing bias would be off by O(1).
        assert!(
            out.get(p as i64).allclose(&single, 1e-6, 1e-6, false),
            "member {p}: outputs differ"
        );
        single.square().sum(Kind::Float).backward();
        for (name, var) in vs.variables() {
            let grad = stacked[&name].grad().get(p as i64);
            assert!(
                grad.allclose(&var.grad(), 1e-5, 1e-6, false),
                "member {p}, {name}: gradients differ"
            );
        }
    }
}

/// A LayerNormMlp that carries its last two input columns to every later layer.
struct Carrying(LayerNormMlp);

impl Net for Carrying {
    fn build(p: &nn::Path, members: Members) -> Self {
        Carrying(LayerNormMlp::carrying(p, 5, &[8, 6], 2, members))
    }
    fn forward(&self, x: &Tensor) -> Tensor {
        self.0.forward(x)
    }
    fn forward_members(&self, x: &Tensor) -> Tensor {
        self.0.forward_members(x)
    }
}

#[test]
fn a_population_of_one_is_the_single_network_bit_for_bit() {
    one_member_is_bit_for_bit::<LayerNormMlp>();
    one_member_is_bit_for_bit::<Carrying>();
    one_member_is_bit_for_bit::<HeadStack>();
}

#[test]
fn each_stacked_member_is_its_own_single_network() {
    stacked_members_are_their_single_networks::<LayerNormMlp>();
    stacked_members_are_their_single_networks::<Carrying>();
    stacked_members_are_their_single_networks::<HeadStack>();
}

/// With the first layer blind to the carried columns, they still move the hidden
/// output (through linear_1) and reach the output as they are; without carrying,
/// the same blind first layer makes the output ignore them.
#[test]
fn carried_columns_reach_every_later_layer() {
    let x = randn(&[4, 5]);
    let moved = x.copy();
    let _ = moved.narrow(1, 3, 2).g_add_scalar_(1.5);
    for carry in [0, 2] {
        let vs = nn::VarStore::new(Device::Cpu);
        let mlp = LayerNormMlp::carrying(&vs.root(), 5, &[8, 6], carry, Members::ONE);
        tch::no_grad(|| {
            let _ = mlp.first.weight.narrow(1, 3, 2).zero_();
        });
        assert_eq!(mlp.output_dim(), 6 + carry);
        assert_eq!(mlp.hidden[0].weight.size(), vec![6, 8 + carry]);
        let (a, b) = (mlp.forward(&x), mlp.forward(&moved));
        let hidden_moved = !a
            .narrow(1, 0, 6)
            .allclose(&b.narrow(1, 0, 6), 1e-6, 1e-6, false);
        assert_eq!(hidden_moved, carry > 0, "carry {carry}");
        if carry > 0 {
            assert!(a.narrow(1, 6, 2).equal(&x.narrow(1, 3, 2)));
        }
    }
}

#[test]
fn shapes_and_first_layer_is_bounded() {
    let vs = nn::VarStore::new(Device::Cpu);
    let mlp = LayerNormMlp::new(&(vs.root() / "torso"), 5, &[8]);
    let y = mlp.forward(&(randn(&[3, 5]) * 100.0));
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
