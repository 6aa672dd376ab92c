"""Expected values of whole ε-conditioned MO-MPO learner steps for agent/tests/golden.rs.

Run from the repo root:  .venv/bin/python agent/tests/golden/make_golden_conditioned_step.py
(make_golden.py runs it too). It writes agent/tests/golden/mpo_step_conditioned.json.

The steps of make_golden_step.py (summed KL constraint), with the learner conditioned on
ε_energy in {0.02, 0.2} (learner.conditioning, relabel = false): the grid has G = 2
points, (task, energy, action_norm) = (0.1, 0.02, 0.02) and (0.1, 0.2, 0.02). Each
snippet of a batch was collected at one grid point, drawn here, and its observations
end with that point's feature, log ε_energy scaled to [-1, 1] over the list (-1 and
+1). What changes is the E-step: every state's weights use its grid point's
temperature eta_{g,k}, and each grid point's temperature dual (eq. 34) averages over
that point's real states only; the G x K temperatures are one Adam parameter, as in
the Rust learner (algo/preferences.rs, algo/estep.rs StateMean::PerGridPoint).
Written with loops over grid points, objectives and states.
"""

import copy
import math

import make_golden_step as base
import torch
import torch.nn.functional as F

ENV_OBS = base.OBS
base.OBS = ENV_OBS + 1  # the networks read the preference feature after the observation
GRID_VALUES = [0.02, 0.2]  # ε_energy; its feature is -1, +1
GRID = [[base.EPSILON[0], v, base.EPSILON[2]] for v in GRID_VALUES]
FEATURE = [-1.0, 1.0]


def config():
    c = base.config("summed")
    c["conditioning"] = {"epsilon": {"energy": GRID_VALUES}, "relabel": False}
    return c


DIMS = dict(
    base.DIMS,
    obs_dim=ENV_OBS + 1,
    obs_leaves=[{"name": "", "dim": ENV_OBS}, {"name": "preference", "dim": 1}],
)


class ConditionedLearner(base.Learner):
    def temperatures(self):
        return len(GRID) * len(base.REWARDS)

    def estep(self, q, rows, batch):
        b_count = batch["observations"].shape[1]
        # Row t*B + b belongs to snippet b, collected at the grid point its feature names.
        feature = batch["observations"][0, :, -1]
        point_of_snippet = [FEATURE.index(feature[b].item()) for b in range(b_count)]
        point = [point_of_snippet[r % b_count] for r in rows]
        eta = (F.softplus(self.temperature_param) + 1e-8).reshape(len(GRID), -1)
        R, K, M = len(rows), len(base.REWARDS), base.M
        weights = torch.zeros(M, R)
        temperature_loss, estep_kl = 0.0, []
        for k in range(K):
            kl_k = 0.0
            for i in range(R):
                w = torch.softmax(q[:, i, k] / eta[point[i], k].item(), 0)
                weights[:, i] += w
                kl_k += (w * torch.log(M * w)).sum().item() / R
            estep_kl.append(kl_k)
            for g in range(len(GRID)):
                mine = [i for i in range(R) if point[i] == g]
                if not mine:
                    continue  # a grid point without states in the batch has no dual term
                log_mean_exp = sum(torch.log(torch.mean(torch.exp(q[:, i, k] / eta[g, k]))) for i in mine) / len(mine)
                temperature_loss = temperature_loss + eta[g, k] * (GRID[g][k] + log_mean_exp)
        return weights, temperature_loss, estep_kl


def make_batch(gen):
    batch = base.make_batch(gen)
    points = torch.randint(0, len(GRID), (base.B,), generator=gen)
    batch["observations"][..., -1] = torch.tensor([FEATURE[g] for g in points])
    return batch


def main():
    gen = torch.Generator().manual_seed(17)
    params = base.initial_parameters(gen)
    initial = {k: base.t(v) for k, v in params.items()}
    learner = ConditionedLearner(copy.deepcopy(params), "summed")
    steps = []
    for _ in range(base.STEPS):
        batch = make_batch(gen)
        noise = base.f32(torch.randn(base.M, (base.T + 1) * base.B, base.D, generator=gen))
        stats = learner.step(batch, noise)
        steps.append(
            {
                "batch": {k: base.t(v) for k, v in batch.items()},
                "noise": base.t(noise),
                "stats": stats,
                "parameters": {k: base.t(v) for k, v in learner.online.items()},
            }
        )
    payload = {"config": config(), "dims": DIMS, "initial_parameters": initial, "steps": steps}
    base.write("mpo_step_conditioned", payload)
    print(
        "snippet features per step (-1: ε_energy 0.02, +1: 0.2):",
        [[int(x) for x in s["batch"]["observations"]["data"][ENV_OBS :: ENV_OBS + 1][: base.B]] for s in steps],
    )
    assert math.isfinite(steps[-1]["stats"]["critic_loss"][0])


if __name__ == "__main__":
    main()
