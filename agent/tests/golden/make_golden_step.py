"""Expected values of whole MO-MPO learner steps for agent/tests/golden.rs, in float64.

Run from the repo root:  .venv/bin/python agent/tests/golden/make_golden_step.py
(make_golden.py runs it too). It writes agent/tests/golden/mpo_step_{summed,per_dimension}.json.

Everything a step needs is made here and read by the Rust test: the learner config
and dimensions (in the serde layout of LearnerConfig and LearnerDims), the initial
parameters of policy and critic by VarStore name, and per step the snippet batch and
the standard-normal noise xi of the M sampled actions (a = mu' + sigma' xi). All
inputs are float32 numbers, so both sides start from the same values; the step itself
is computed here in float64 from the paper's formulas (appendix A networks, C.2
Retrace, E.1 eqs. 32-34, C.3 eqs. 16-20, Algorithm 3), written with loops over
objectives, states and heads rather than the Rust code's vectorised forms, and with
torch.optim.Adam for every optimizer. Three steps with target_update_period 2: the
second step has online != target networks (so it tells them apart), the third starts
from targets copied after the second.

Choices that are the project's, not the paper's, transcribed here as documented in
the Rust modules: Gaussian policy head (nets/policy.rs), the critic's shared first
layer and per-objective heads (nets/critic/), padding after an episode's end (no
critic regression there, no policy fit at states never acted from, mompo.rs), the
action-norm objective on the executed action (objectives/mod.rs), duals as
softplus(param) + 1e-8 with their own Adam and a floor of -18 on the parameter after
the update (dual.rs).
"""

import copy
import json
import math
import pathlib

import torch
import torch.nn.functional as F

torch.set_default_dtype(torch.float64)
OUT = pathlib.Path(__file__).resolve().parent
Normal = torch.distributions.Normal

T, B, OBS, D, M = 3, 2, 3, 2, 4  # snippet length, snippets, obs size, action dims, samples
REWARDS = ["task", "energy", "action_norm"]  # env reward columns
EPSILON = [0.1, 0.05, 0.02]
HEAD_OF = {"task": 0, "energy": 1}  # action_norm has no critic: -||a_env||_2
LOW, HIGH = [-1.0, -0.5], [1.0, 2.0]
POLICY_LAYERS, CRITIC_LAYERS = [8, 6], [8, 6]
MIN_VARIANCE = 1e-4
GAMMA, LR, ADAM_EPS, DUAL_LR = 0.99, 3e-3, 1e-3, 1e-2
BETA_MEAN, BETA_COV = 1e-3, 1e-5
INIT_TEMPERATURE, INIT_ALPHA_MEAN, INIT_ALPHA_COV = 1.0, 1.0, 10.0
TARGET_PERIOD, STEPS = 2, 3


def t(x):
    x = torch.as_tensor(x)
    return {"shape": list(x.shape), "data": x.detach().flatten().tolist()}


def f32(x):
    """x rounded to float32 and held as float64: an input both sides read exactly."""
    return torch.as_tensor(x).to(torch.float32).to(torch.float64)


def softplus_inv(v):
    return math.log(math.expm1(v - 1e-8))


def write(name, payload):
    """agent/tests/golden/<name>.json, in the layout every golden file has."""
    (OUT / f"{name}.json").write_text(json.dumps(payload, indent=1) + "\n")


def config(kl_constraint):
    return {
        "algorithm": {"kind": "mo_mpo"},
        "objectives": [
            {"name": "task", "epsilon": EPSILON[0]},
            {"name": "energy", "epsilon": EPSILON[1]},
            {"name": "action_norm", "epsilon": EPSILON[2], "source": "action_norm"},
        ],
        "network": {
            "policy_layers": POLICY_LAYERS,
            "critic_layers": CRITIC_LAYERS,
            "critic_shared_layers": 1,
            "tanh_on_action_mean": True,
            "min_variance": MIN_VARIANCE,
            "tanh_on_critic_action": True,
        },
        "mpo": {
            "num_samples": M,
            "beta_mean": BETA_MEAN,
            "beta_cov": BETA_COV,
            "kl_constraint": kl_constraint,
            "init_temperature": INIT_TEMPERATURE,
            "init_alpha_mean": INIT_ALPHA_MEAN,
            "init_alpha_cov": INIT_ALPHA_COV,
            "dual_learning_rate": DUAL_LR,
            "retrace_length": T,
            "discount": GAMMA,
            "target_update_period": TARGET_PERIOD,
            "learning_rate": LR,
            "adam_eps": ADAM_EPS,
            "batch_size": B,
            "replay_capacity": 100,
        },
        "seed": 0,
        "device": "cpu",
    }


DIMS = {
    "obs_dim": OBS,
    "action": {"continuous": {"dim": D}},
    "reward_names": REWARDS,
    "obs_leaves": [],
    "action_bounds": {"low": LOW, "high": HIGH},
}


def initial_parameters(gen):
    """Policy and critic parameters by VarStore name (float32 values)."""

    def uniform(shape, fan_in):
        bound = 1.0 / math.sqrt(fan_in)
        return f32((torch.rand(shape, generator=gen) * 2 - 1) * bound)

    def around_one(n):  # LayerNorm gains away from 1, so that they matter
        return f32(1.0 + 0.2 * torch.randn(n, generator=gen))

    h1, h2 = POLICY_LAYERS
    c1, c2 = CRITIC_LAYERS
    heads = len(HEAD_OF)
    p = {
        "policy.torso.linear_0.weight": uniform((h1, OBS), OBS),
        "policy.torso.linear_0.bias": uniform((h1,), OBS),
        "policy.torso.layer_norm.weight": around_one(h1),
        "policy.torso.layer_norm.bias": f32(0.1 * torch.randn(h1, generator=gen)),
        "policy.torso.linear_1.weight": uniform((h2, h1), h1),
        "policy.torso.linear_1.bias": uniform((h2,), h1),
        "policy.head.weight": uniform((2 * D, h2), h2),
        "policy.head.bias": uniform((2 * D,), h2),
        "critic.shared.obs.weight": uniform((c1, OBS), OBS + D),
        "critic.shared.obs.bias": uniform((c1,), OBS + D),
        "critic.shared.action.weight": uniform((c1, D), OBS + D),
        "critic.shared.layer_norm.weight": around_one(c1),
        "critic.shared.layer_norm.bias": f32(0.1 * torch.randn(c1, generator=gen)),
        "critic.heads.linear_0.weight": uniform((heads, c1, c2), c1),
        "critic.heads.linear_0.bias": uniform((heads, 1, c2), c1),
        "critic.heads.linear_1.weight": uniform((heads, c2, 1), c2),
        "critic.heads.linear_1.bias": uniform((heads, 1, 1), c2),
    }
    return {k: v.clone().requires_grad_(True) for k, v in p.items()}


def policy(p, obs):
    """Table 2 policy: Linear -> LayerNorm -> tanh, Linear -> ELU, then a head giving
    mean = tanh(.) and std = softplus(.) + sqrt(min variance). obs [N, OBS] -> [N, D] x2."""
    h = obs @ p["policy.torso.linear_0.weight"].T + p["policy.torso.linear_0.bias"]
    h = torch.tanh(
        F.layer_norm(h, (h.shape[-1],), p["policy.torso.layer_norm.weight"], p["policy.torso.layer_norm.bias"])
    )
    h = F.elu(h @ p["policy.torso.linear_1.weight"].T + p["policy.torso.linear_1.bias"])
    out = h @ p["policy.head.weight"].T + p["policy.head.bias"]
    return torch.tanh(out[:, :D]), F.softplus(out[:, D:]) + math.sqrt(MIN_VARIANCE)


def critic(p, obs, actions):
    """Per-objective Q heads on a shared first layer Linear([s, tanh a]) -> LayerNorm ->
    tanh. obs [N, OBS], actions [..., N, D] -> [..., N, C]."""
    x = torch.cat([obs.expand(*actions.shape[:-1], obs.shape[-1]), torch.tanh(actions)], -1)
    w = torch.cat([p["critic.shared.obs.weight"], p["critic.shared.action.weight"]], 1)
    h = x @ w.T + p["critic.shared.obs.bias"]
    h = torch.tanh(
        F.layer_norm(h, (h.shape[-1],), p["critic.shared.layer_norm.weight"], p["critic.shared.layer_norm.bias"])
    )
    columns = []
    for c in range(len(HEAD_OF)):
        z = F.elu(h @ p["critic.heads.linear_0.weight"][c] + p["critic.heads.linear_0.bias"][c])
        columns.append((z @ p["critic.heads.linear_1.weight"][c] + p["critic.heads.linear_1.bias"][c])[..., 0])
    return torch.stack(columns, -1)


def executed(a):
    """The action the env executes: clipped to [-1, 1], mapped onto [low, high]."""
    lo, hi = torch.tensor(LOW), torch.tensor(HIGH)
    return (lo + hi) / 2 + (hi - lo) / 2 * a.clamp(-1.0, 1.0)


def make_batch(gen):
    """Snippet 0: three real steps, no terminal. Snippet 1: step 1 ends the episode
    (discount 0), step 2 is padding (valid 0, reward 0)."""
    discounts = torch.ones(T, B)
    valid = torch.ones(T, B)
    discounts[1, 1] = 0.0
    discounts[2, 1] = 0.0
    valid[2, 1] = 0.0
    rewards = torch.randn(T, B, len(REWARDS), generator=gen)
    rewards[2, 1] = 0.0
    return {
        "observations": f32(torch.randn(T + 1, B, OBS, generator=gen)),
        "actions": f32(0.8 * torch.randn(T, B, D, generator=gen)),
        "rewards": f32(rewards),
        "discounts": discounts,
        "behaviour_log_probs": f32(-1.0 + 0.5 * torch.randn(T, B, generator=gen)),
        "valid": valid,
    }


def retrace(q_taken, v_next, rewards, discounts, valid, c):
    """C.2 eq. 15 per snippet and head: Q_ret(s_t, a_t) = Q'(s_t, a_t)
    + sum_{j=t}^{end-1} gamma^(j-t) (prod_{z=t+1}^{j} c_z d_{z-1}) delta_j, with `end` the
    snippet's first padding step (the episode is over there) and d cutting at a terminal."""
    targets = torch.zeros_like(q_taken)
    for b in range(B):
        end = next((z for z in range(T) if valid[z, b] == 0.0), T)
        for s in range(end):
            for k in range(q_taken.shape[-1]):
                total = q_taken[s, b, k].item()
                for j in range(s, end):
                    trace = GAMMA ** (j - s)
                    for z in range(s + 1, j + 1):
                        trace *= c[z, b].item() * discounts[z - 1, b].item()
                    delta = rewards[j, b, k] + GAMMA * discounts[j, b] * v_next[j, b, k] - q_taken[j, b, k]
                    total += trace * delta.item()
                targets[s, b, k] = total
    return targets


def real_rows(valid, discounts):
    """Row t*B + b of the (T+1)B states is fitted when step t is real or when a real,
    non-terminal step t-1 leads into it."""
    rows = []
    for t_ in range(T + 1):
        for b in range(B):
            acted = t_ < T and valid[t_, b] == 1.0
            reached = t_ > 0 and valid[t_ - 1, b] == 1.0 and discounts[t_ - 1, b] == 1.0
            if acted or reached:
                rows.append(t_ * B + b)
    return rows


class Learner:
    def temperatures(self):
        """How many temperatures: one per objective."""
        return len(REWARDS)

    def __init__(self, params, kl_constraint):
        self.per_dim = kl_constraint == "per_dimension"
        self.online = params
        self.target = {k: v.detach().clone() for k, v in params.items()}
        pol = [v for k, v in params.items() if k.startswith("policy.")]
        cri = [v for k, v in params.items() if k.startswith("critic.")]
        self.policy_opt = torch.optim.Adam(pol, lr=LR, eps=ADAM_EPS)
        self.critic_opt = torch.optim.Adam(cri, lr=LR, eps=ADAM_EPS)
        p = D if self.per_dim else 1
        # The Rust duals start from float32 parameters.
        self.temperature_param = f32([softplus_inv(INIT_TEMPERATURE)] * self.temperatures()).requires_grad_(True)
        alpha0 = [softplus_inv(INIT_ALPHA_MEAN)] * p + [softplus_inv(INIT_ALPHA_COV)] * p
        self.alpha_param = f32(alpha0).requires_grad_(True)
        self.dual_opt = torch.optim.Adam([self.temperature_param, self.alpha_param], lr=DUAL_LR, eps=1e-8)
        self.steps = 0

    def estep(self, q, rows, batch):
        """Weights [M, R] summed over objectives, the temperature loss of eq. 34 and the
        realised KL per objective, at the real states `rows`."""
        eta = F.softplus(self.temperature_param) + 1e-8
        R, K = len(rows), len(REWARDS)
        weights = torch.zeros(M, R)
        temperature_loss, estep_kl = 0.0, []
        for k in range(K):
            kl_k = 0.0
            for i in range(R):
                w = torch.softmax(q[:, i, k] / eta[k].item(), 0)
                weights[:, i] += w
                kl_k += (w * torch.log(M * w)).sum().item() / R
            estep_kl.append(kl_k)
            # eq. 34, the integral over pi_old as the mean over the M samples
            log_mean_exp = sum(torch.log(torch.mean(torch.exp(q[:, i, k] / eta[k]))) for i in range(R)) / R
            temperature_loss = temperature_loss + eta[k] * (EPSILON[k] + log_mean_exp)
        return weights, temperature_loss, estep_kl

    def step(self, batch, noise):
        obs_all = batch["observations"].reshape(-1, OBS)  # row t*B + b
        obs_taken = obs_all[: T * B]
        act = batch["actions"].reshape(-1, D)
        valid = batch["valid"]

        # 1. Policy evaluation (C.2) with the target networks.
        with torch.no_grad():
            mean_t, std_t = policy(self.target, obs_all)
            samples = mean_t + std_t * noise  # [M, N, D] ~ pi_old
            q_samples = critic(self.target, obs_all, samples)  # [M, N, C]
            v = q_samples.mean(0).reshape(T + 1, B, -1)
            q_taken = critic(self.target, obs_taken, act).reshape(T, B, -1)
            log_pi_old = Normal(mean_t[: T * B], std_t[: T * B]).log_prob(act).sum(-1).reshape(T, B)
            c = torch.minimum(torch.ones(T, B), torch.exp(log_pi_old - batch["behaviour_log_probs"]))
            heads_rewards = batch["rewards"][..., [REWARDS.index(n) for n in HEAD_OF]]
            targets = retrace(q_taken, v[1:], heads_rewards, batch["discounts"], valid, c)
        q_online = critic(self.online, obs_taken, act).reshape(T, B, -1)
        per_head = []
        for k in range(len(HEAD_OF)):
            errors = [
                (q_online[t_, b, k] - targets[t_, b, k]) ** 2
                for t_ in range(T)
                for b in range(B)
                if valid[t_, b] == 1.0
            ]
            per_head.append(0.5 * sum(errors) / len(errors))
        self.critic_opt.zero_grad()
        sum(per_head).backward()
        self.critic_opt.step()

        # 2. E-step (eqs. 32-34) at the real states, on the same samples.
        rows = real_rows(valid, batch["discounts"])
        a = samples[:, rows]  # [M, R, D]
        q = torch.stack(
            [q_samples[:, rows, HEAD_OF[n]] if n in HEAD_OF else -executed(a).norm(dim=-1) for n in REWARDS], -1
        )  # [M, R, K]
        weights, temperature_loss, estep_kl = self.estep(q, rows, batch)

        # 3. M-step (eqs. 16-20): decoupled policies, KL(pi_old || .) per dimension.
        mean_o, std_o = policy(self.online, obs_all[rows])
        mt, st = mean_t[rows], std_t[rows]
        log_lik = Normal(mean_o, st).log_prob(a).sum(-1) + Normal(mt, std_o).log_prob(a).sum(-1)
        nll = -(weights * log_lik).sum(0).mean()
        kl_mean = torch.distributions.kl_divergence(Normal(mt, st), Normal(mean_o, st)).mean(0)  # [D]
        kl_cov = torch.distributions.kl_divergence(Normal(mt, st), Normal(mt, std_o)).mean(0)  # [D]
        if not self.per_dim:  # eq. 20: the KL of the whole Gaussian
            kl_mean, kl_cov = kl_mean.sum(0, keepdim=True), kl_cov.sum(0, keepdim=True)
        alpha = (F.softplus(self.alpha_param) + 1e-8).reshape(2, -1)
        policy_loss, alpha_loss = nll, 0.0
        for d in range(kl_mean.shape[0]):
            policy_loss = policy_loss + alpha[0, d].detach() * kl_mean[d] + alpha[1, d].detach() * kl_cov[d]
            alpha_loss = alpha_loss + alpha[0, d] * (BETA_MEAN - kl_mean[d].detach())
            alpha_loss = alpha_loss + alpha[1, d] * (BETA_COV - kl_cov[d].detach())
        self.policy_opt.zero_grad()
        self.dual_opt.zero_grad()
        (policy_loss + alpha_loss + temperature_loss).backward()
        self.policy_opt.step()
        self.dual_opt.step()
        with torch.no_grad():
            self.temperature_param.clamp_(min=-18.0)
            self.alpha_param.clamp_(min=-18.0)

        # 4. Target networks (C.1).
        self.steps += 1
        if self.steps % TARGET_PERIOD == 0:
            self.target = {k: v.detach().clone() for k, v in self.online.items()}

        alpha = (F.softplus(self.alpha_param) + 1e-8).reshape(2, -1)
        return {
            "critic_loss": [x.item() for x in per_head],
            "temperature": (F.softplus(self.temperature_param) + 1e-8).tolist(),
            "estep_kl": estep_kl,
            "q_mean": q.mean((0, 1)).tolist(),
            # LearnerStats: each part's mean over its multipliers and KLs
            "alpha": alpha.mean(1).tolist(),
            "policy_kl": [kl_mean.mean().item(), kl_cov.mean().item()],
            "alpha_by_part": alpha.tolist(),
        }


def main():
    for kl_constraint in ["summed", "per_dimension"]:
        gen = torch.Generator().manual_seed(13)
        params = initial_parameters(gen)
        initial = {k: t(v) for k, v in params.items()}
        learner = Learner(copy.deepcopy(params), kl_constraint)
        steps = []
        for _ in range(STEPS):
            batch = make_batch(gen)
            noise = f32(torch.randn(M, (T + 1) * B, D, generator=gen))
            stats = learner.step(batch, noise)
            steps.append(
                {
                    "batch": {k: t(v) for k, v in batch.items()},
                    "noise": t(noise),
                    "stats": stats,
                    "parameters": {k: t(v) for k, v in learner.online.items()},
                }
            )
        payload = {"config": config(kl_constraint), "dims": DIMS, "initial_parameters": initial, "steps": steps}
        write(f"mpo_step_{kl_constraint}", payload)


if __name__ == "__main__":
    main()
