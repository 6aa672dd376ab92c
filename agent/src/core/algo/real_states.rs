//! The states a learner step fits and how each counts, per member: the real states
//! of a snippet batch (acted from, or bootstrapped into from a real non-terminal
//! step), gathered member by member to the widest member's count with weights that
//! make every mean over states each member's own mean; and the critic loss over real
//! steps. Padding after an episode's end is never fitted.
//!
//! Shape legend: P members, T snippet length, B snippets, N = (T+1)B states, R real
//! states of the widest member, C critics.

use tch::{Kind, Tensor};

/// Which of each member's N = (T+1)B states the E- and M-steps see, and how each
/// state counts in a member's mean over states.
#[derive(Debug)]
pub struct RealStates {
    /// `[P, R]` i64: member p's real rows first, in row order, then (up to R, the
    /// largest member's count) copies of its first real row. `None` when every row
    /// of every member is real (R = N).
    pub index: Option<Tensor>,
    /// `[P, R]` f32: 1 / (member's real count) at its real rows, 0 at the copies.
    pub weight: Tensor,
}

/// The real states of P members' snippet batches. Row (t, b) is real when step t is
/// real (`valid`), or when step t-1 is real and not terminal (s_t is then the state
/// it bootstraps from: the next state of a step, or the last observation of a
/// time-limited episode). One member alone gets exactly its real rows (no copies).
/// # Shapes
/// `valid [P, T, B]`, `discounts [P, T, B]`.
pub fn real_states(valid: &Tensor, discounts: &Tensor) -> RealStates {
    let size = valid.size();
    let (p, b) = (size[0], size[2]);
    let none = valid.zeros_like().narrow(1, 0, 1);
    let acted = Tensor::cat(&[valid.shallow_clone(), none.shallow_clone()], 1);
    let bootstrapped = Tensor::cat(&[none, valid * discounts], 1);
    let real = acted.maximum(&bootstrapped).gt(0.5).reshape([p, -1]);
    debug_assert_eq!(real.size()[1] % b, 0);
    real_rows(&real)
}

/// Each member's real rows of `real [P, N]` (bool), gathered to the widest member's
/// count as `real_states` does. One member alone gets exactly its real rows.
pub fn real_rows(real: &Tensor) -> RealStates {
    let (p, n) = (real.size()[0], real.size()[1]);
    let counts = real.sum_dim_intlist(1, true, Kind::Int64);
    // One host read per step: the widest and narrowest members' counts.
    let extremes =
        Vec::<i64>::try_from(&Tensor::stack(&[counts.max(), counts.min()], 0)).expect("i64 counts");
    let widest = extremes[0];
    if extremes[1] == n {
        let weight = Tensor::full([p, n], 1.0 / n as f64, (Kind::Float, real.device()));
        return RealStates {
            index: None,
            weight,
        };
    }
    // Real row r of member p goes to slot (number of real rows before it); the rest to
    // a spare slot that is cut off.
    let slots = (real.cumsum(1, Kind::Int64) - 1).where_self(real, &Tensor::from(widest));
    let rows = Tensor::arange(n, (Kind::Int64, real.device()))
        .unsqueeze(0)
        .expand([p, n], false)
        .contiguous();
    let first = real.to_kind(Kind::Int64).argmax(1, true);
    let index = first
        .expand([p, widest + 1], false)
        .contiguous()
        .scatter(1, &slots, &rows)
        .narrow(1, 0, widest);
    let position = Tensor::arange(widest, (Kind::Int64, real.device())).unsqueeze(0);
    let counted = position.lt_tensor(&counts).to_kind(Kind::Float);
    // Every snippet has a real first step, so no member counts 0; the floor keeps a
    // malformed batch from dividing by it.
    RealStates {
        index: Some(index),
        weight: counted / counts.clamp_min(1).to_kind(Kind::Float),
    }
}

/// Each member's rows along axis `dim` of `t`, at `index [P, R]`.
/// # Shapes
/// `t [P, .., N, ..]` (N at `dim`) `-> [P, .., R, ..]`.
pub fn gather_states(t: &Tensor, index: &Tensor, dim: i64) -> Tensor {
    let size = t.size();
    let mut idx = index.shallow_clone();
    for _ in 1..dim {
        idx = idx.unsqueeze(1);
    }
    for _ in (dim as usize + 1)..size.len() {
        idx = idx.unsqueeze(-1);
    }
    let mut shape = size.clone();
    shape[dim as usize] = index.size()[1];
    t.gather(dim, &idx.expand(shape.as_slice(), false), false)
}

/// `0.5 * mean over real rows of err^2`, per column (per member: leading axes of
/// `err` and `valid` are kept).
/// # Shapes
/// `err [.., N, C]`, `valid [.., N]` (1 real, 0 padding) `-> [.., C]`.
pub fn masked_half_mse(err: &Tensor, valid: &Tensor) -> Tensor {
    let real = valid.sum_dim_intlist(-1, true, Kind::Float).clamp_min(1.0);
    (err.square() * valid.unsqueeze(-1)).sum_dim_intlist(-2, false, Kind::Float) / real * 0.5
}
