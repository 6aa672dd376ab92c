"""Expected values of whole MO-V-MPO / scalarized V-MPO learner steps for
agent/tests/golden_vmpo.rs, in float64.

Run from the repo root:  .venv/bin/python agent/tests/golden/make_golden_vmpo_step.py
It writes agent/tests/golden/vmpo_step_{gaussian,categorical}.json.

As make_golden_step.py does for MO-MPO, everything a step needs is made here and read
by the Rust test: the learner config and dimensions (serde layout of LearnerConfig and
LearnerDims), the initial parameters of policy and value network by VarStore name,
and per step the unroll batch. The policies have plain torsos, so a V-MPO step draws
no noise. All inputs are float32 numbers; the step is computed in float64 from
appendix D, written with loops over unrolls, steps, objectives and pairs rather than
the Rust code's vectorised forms, and torch.optim.Adam for every optimizer:

- D.1 eq. 21: V_c at every state from the online value net; per real step t of an
  unroll, G_t = sum_{l=t}^{end-1} gamma^(l-t) r_l + gamma^(end-t) V(s_end), `end` the
  unroll's end or its first padding step, the sum cut after a terminal step;
  A = G - V; the value loss 0.5 (V - G)^2 averaged over real steps, summed over heads.
- D.2.1 eqs. 22-24 over the real pairs (p_old uniform over them) with `vmpo.top_k =
  "joint"`: keep the top 50% of the pairs by s = sum_k A_k / eta_k (k = max(1,
  floor(n / 2)), ties in; Song et al. 2020's top-k, applied once), fit weights
  exp(s) / sum_top exp(s) on them (the product of the q_k, see
  docs/algorithms/mo-v-mpo-preferences.md), and per objective the dual
  eta_k (eps_k + log mean_{top} exp(A_k / eta_k)). With one objective (the categorical
  case) this is V-MPO's step, and that file's values are the ones of the rule before
  issue 38.
- D.2.2 eq. 25: maximise sum_k sum_i q_k(i) log pi(a_i|s_i) under KL(pi_old || pi) < beta
  with Lagrangian relaxation (V-MPO): alpha as a multiplier, stop-gradients as in
  V-MPO's loss. Gaussian policies use MO-MPO's decoupled form (eqs. 18-20) with one
  alpha_mu and one alpha_Sigma; categorical ones one alpha.
- pi_old is copied from the online policy every `target_update_period` steps.

Choices that are the project's, not the paper's, transcribed as documented in the
Rust modules: policy heads (nets/policy.rs), the value net's shared LayerNorm layer and
per-head layers (nets/value.rs), bootstrapping at a truncation and before padding
(movmpo.rs), duals as softplus(param) + 1e-8 with their own Adam and a floor of -18
(dual.rs). Three steps with target_update_period 2, as for MO-MPO.
"""

import copy
import math
import pathlib

import torch
import torch.nn.functional as F
from make_golden_step import f32, softplus_inv, t, write

torch.set_default_dtype(torch.float64)
OUT = pathlib.Path(__file__).resolve().parent
Normal = torch.distributions.Normal

T, B, OBS = 4, 3, 3  # unroll length, unrolls, observation size
POLICY_LAYERS, CRITIC_LAYERS = [8, 6], [8, 6]
MIN_VARIANCE = 1e-4
GAMMA, LR, ADAM_EPS, DUAL_LR = 0.95, 3e-3, 1e-5, 1e-2
BETA_MEAN, BETA_COV, BETA_CATEGORICAL = 0.1, 1e-5, 0.01
INIT_TEMPERATURE, INIT_ALPHA_MEAN, INIT_ALPHA_COV, INIT_ALPHA_CATEGORICAL = 1.0, 1.0, 1.0, 1.0
TOP_K_FRACTION = 0.5
TARGET_PERIOD, STEPS = 2, 3

# Gaussian case: MO-V-MPO, two objectives, two critic heads, D = 2.
GAUSSIAN = {
    "name": "gaussian",
    "rewards": ["task", "energy"],
    "action": {"continuous": {"dim": 2}},
    "algorithm": {"kind": "mo_vmpo"},
    "objectives": [{"name": "task", "epsilon": 0.1}, {"name": "energy", "epsilon": 0.05}],
    # [K_env, C]: which reward each head learns
    "head_weights": [[1.0, 0.0], [0.0, 1.0]],
    "epsilon": [0.1, 0.05],
}
# Categorical case: scalarized V-MPO, one head on 0.7 treasure + 0.3 time, A = 4.
CATEGORICAL = {
    "name": "categorical",
    "rewards": ["treasure", "time"],
    "action": {"discrete": {"n": 4}},
    "algorithm": {
        "kind": "scalarized_vmpo",
        "epsilon": 0.1,
        "weights": [{"name": "treasure", "weight": 0.7}, {"name": "time", "weight": 0.3}],
    },
    "objectives": [],
    "head_weights": [[0.7], [0.3]],
    "epsilon": [0.1],
}


def config(case):
    return {
        "algorithm": case["algorithm"],
        "objectives": case["objectives"],
        "network": {
            "policy_layers": POLICY_LAYERS,
            "critic_layers": CRITIC_LAYERS,
            "critic_shared_layers": 1,
            "tanh_on_action_mean": True,
            "min_variance": MIN_VARIANCE,
        },
        "vmpo": {
            "unroll_length": T,
            "discount": GAMMA,
            "top_k_fraction": TOP_K_FRACTION,
            "beta_mean": BETA_MEAN,
            "beta_cov": BETA_COV,
            "beta_categorical": BETA_CATEGORICAL,
            "init_temperature": INIT_TEMPERATURE,
            "init_alpha_mean": INIT_ALPHA_MEAN,
            "init_alpha_cov": INIT_ALPHA_COV,
            "init_alpha_categorical": INIT_ALPHA_CATEGORICAL,
            "dual_learning_rate": DUAL_LR,
            "learning_rate": LR,
            "adam_eps": ADAM_EPS,
            "batch_size": B,
            "target_update_period": TARGET_PERIOD,
        },
        "seed": 0,
        "device": "cpu",
    }


def dims(case):
    d = {"obs_dim": OBS, "action": case["action"], "reward_names": case["rewards"], "obs_leaves": []}
    if "continuous" in case["action"]:
        d["action_bounds"] = {"low": [-1.0, -0.5], "high": [1.0, 2.0]}
    return d


def policy_outputs(case):
    """Width of the policy head: [mean, std] per dimension, or one logit per action."""
    if "continuous" in case["action"]:
        return 2 * case["action"]["continuous"]["dim"]
    return case["action"]["discrete"]["n"]


def initial_parameters(case, gen):
    """Policy and value-net parameters by VarStore name (float32 values)."""

    def uniform(shape, fan_in):
        bound = 1.0 / math.sqrt(fan_in)
        return f32((torch.rand(shape, generator=gen) * 2 - 1) * bound)

    def around_one(n):  # LayerNorm gains away from 1, so that they matter
        return f32(1.0 + 0.2 * torch.randn(n, generator=gen))

    h1, h2 = POLICY_LAYERS
    c1, c2 = CRITIC_LAYERS
    heads = len(case["head_weights"][0])
    out = policy_outputs(case)
    p = {
        "policy.torso.linear_0.weight": uniform((h1, OBS), OBS),
        "policy.torso.linear_0.bias": uniform((h1,), OBS),
        "policy.torso.layer_norm.weight": around_one(h1),
        "policy.torso.layer_norm.bias": f32(0.1 * torch.randn(h1, generator=gen)),
        "policy.torso.linear_1.weight": uniform((h2, h1), h1),
        "policy.torso.linear_1.bias": uniform((h2,), h1),
        "policy.head.weight": uniform((out, h2), h2),
        "policy.head.bias": uniform((out,), h2),
        "critic.shared.linear_0.weight": uniform((c1, OBS), OBS),
        "critic.shared.linear_0.bias": uniform((c1,), OBS),
        "critic.shared.layer_norm.weight": around_one(c1),
        "critic.shared.layer_norm.bias": f32(0.1 * torch.randn(c1, generator=gen)),
        "critic.heads.linear_0.weight": uniform((heads, c1, c2), c1),
        "critic.heads.linear_0.bias": uniform((heads, 1, c2), c1),
        # Larger than the usual init so that values, and so advantages, are not tiny.
        "critic.heads.linear_1.weight": f32(3.0 * uniform((heads, c2, 1), c2)),
        "critic.heads.linear_1.bias": uniform((heads, 1, 1), c2),
    }
    return {k: v.clone().requires_grad_(True) for k, v in p.items()}


def torso(p, obs):
    """Table 2 torso: Linear -> LayerNorm -> tanh, then Linear -> ELU."""
    h = obs @ p["policy.torso.linear_0.weight"].T + p["policy.torso.linear_0.bias"]
    h = torch.tanh(
        F.layer_norm(h, (h.shape[-1],), p["policy.torso.layer_norm.weight"], p["policy.torso.layer_norm.bias"])
    )
    h = F.elu(h @ p["policy.torso.linear_1.weight"].T + p["policy.torso.linear_1.bias"])
    return h @ p["policy.head.weight"].T + p["policy.head.bias"]


def gaussian(p, obs, d):
    """mean = tanh(.), std = softplus(.) + sqrt(min variance). -> [N, D] x2."""
    out = torso(p, obs)
    return torch.tanh(out[:, :d]), F.softplus(out[:, d:]) + math.sqrt(MIN_VARIANCE)


def value_net(p, obs):
    """A.3's MO-V-MPO critic in small: a shared Linear -> LayerNorm -> tanh, then per head
    Linear -> ELU -> Linear. obs [N, OBS] -> [N, C]."""
    h = obs @ p["critic.shared.linear_0.weight"].T + p["critic.shared.linear_0.bias"]
    h = torch.tanh(
        F.layer_norm(h, (h.shape[-1],), p["critic.shared.layer_norm.weight"], p["critic.shared.layer_norm.bias"])
    )
    columns = []
    for c in range(p["critic.heads.linear_0.weight"].shape[0]):
        z = F.elu(h @ p["critic.heads.linear_0.weight"][c] + p["critic.heads.linear_0.bias"][c])
        columns.append((z @ p["critic.heads.linear_1.weight"][c] + p["critic.heads.linear_1.bias"][c])[:, 0])
    return torch.stack(columns, -1)


def make_batch(case, gen):
    """Unroll 0: four real steps, none terminal. Unroll 1: step 1 ends the episode
    (discount 0), steps 2-3 padding. Unroll 2: step 2 is truncated (discount 1, real),
    step 3 padding, so it bootstraps from V(s_3)."""
    discounts = torch.ones(T, B)
    valid = torch.ones(T, B)
    discounts[1:, 1] = 0.0
    valid[2:, 1] = 0.0
    discounts[3, 2] = 0.0
    valid[3, 2] = 0.0
    rewards = torch.randn(T, B, len(case["rewards"]), generator=gen)
    rewards[valid == 0.0] = 0.0
    if "continuous" in case["action"]:
        d = case["action"]["continuous"]["dim"]
        actions = f32(0.8 * torch.randn(T, B, d, generator=gen))
    else:
        n = case["action"]["discrete"]["n"]
        actions = torch.randint(0, n, (T, B), generator=gen)
    return {
        "observations": f32(torch.randn(T + 1, B, OBS, generator=gen)),
        "actions": actions,
        "rewards": f32(rewards),
        "discounts": discounts,
        "behaviour_log_probs": f32(-1.0 + 0.5 * torch.randn(T, B, generator=gen)),
        "valid": valid,
    }


def n_step_targets(values, rewards, discounts, valid):
    """Eq. 21 per unroll, head and real step (see the module docstring). -> [T, B, C]."""
    targets = torch.zeros(T, B, values.shape[-1])
    for b in range(B):
        end = next((z for z in range(T) if valid[z, b] == 0.0), T)
        for s in range(end):
            for c in range(values.shape[-1]):
                g, scale = 0.0, 1.0
                for z in range(s, end):
                    g += scale * rewards[z, b, c].item()
                    scale *= GAMMA * discounts[z, b].item()
                targets[s, b, c] = g + scale * values[end, b, c].item()
    return targets


def step_one(advantages, eta, epsilon):
    """Eqs. 22-24 under `vmpo.top_k = "joint"` (the default) over the real pairs.
    advantages: per objective, a list of floats. -> fit weights (list, summing to 1),
    the dual loss (tensor in eta), KL(q_k || p_old) per objective."""
    n, n_obj = len(advantages[0]), len(advantages)
    lam = [1.0 / eta[k].item() if epsilon[k] > 0.0 else 0.0 for k in range(n_obj)]
    # One selection for all objectives: the top 50% of s_i = sum_k A_ki / eta_k (the
    # log-density ratio of p_old prod_k exp(A_k / eta_k)), k = max(1, floor(n / 2)),
    # ties in.
    score = [sum(lam[k] * advantages[k][i] for k in range(n_obj)) for i in range(n)]
    k_top = max(1, math.floor(TOP_K_FRACTION * n))
    threshold = sorted(score, reverse=True)[k_top - 1]
    # The float32 Rust side must select the same pairs.
    gap = min((abs(x - threshold) for x in score if x != threshold), default=1.0)
    assert gap > 1e-4, f"scores too close to the top-k threshold ({gap})"
    top = [i for i in range(n) if score[i] >= threshold]
    # Fit weights: the product of the q_k on the selection, one distribution.
    z = sum(math.exp(score[i]) for i in top)
    weights = [math.exp(score[i]) / z if i in top else 0.0 for i in range(n)]
    dual, kl = 0.0, []
    for k in range(n_obj):
        if epsilon[k] == 0.0:
            kl.append(0.0)
            continue
        mean_exp = sum(torch.exp(advantages[k][i] / eta[k]) for i in top) / len(top)
        dual = dual + eta[k] * (epsilon[k] + torch.log(mean_exp))
        zk = sum(math.exp(advantages[k][i] / eta[k].item()) for i in top)
        q = [math.exp(advantages[k][i] / eta[k].item()) / zk for i in top]
        kl.append(sum(w * math.log(w * n) for w in q))
    return weights, dual, kl


class Learner:
    def __init__(self, case, params):
        self.case = case
        self.gaussian = "continuous" in case["action"]
        self.online = params
        self.target = {k: v.detach().clone() for k, v in params.items() if k.startswith("policy.")}
        pol = [v for k, v in params.items() if k.startswith("policy.")]
        cri = [v for k, v in params.items() if k.startswith("critic.")]
        self.policy_opt = torch.optim.Adam(pol, lr=LR, eps=ADAM_EPS)
        self.critic_opt = torch.optim.Adam(cri, lr=LR, eps=ADAM_EPS)
        self.temperature_param = f32([softplus_inv(INIT_TEMPERATURE)] * len(case["epsilon"])).requires_grad_(True)
        alpha0 = (
            [softplus_inv(INIT_ALPHA_MEAN), softplus_inv(INIT_ALPHA_COV)]
            if self.gaussian
            else [softplus_inv(INIT_ALPHA_CATEGORICAL)]
        )
        self.alpha_param = f32(alpha0).requires_grad_(True)
        self.dual_opt = torch.optim.Adam([self.temperature_param, self.alpha_param], lr=DUAL_LR, eps=1e-8)
        self.steps = 0

    def step(self, batch):
        valid = batch["valid"]
        heads = len(self.case["head_weights"][0])
        # 1. Policy evaluation (D.1).
        values = value_net(self.online, batch["observations"].reshape(-1, OBS)).reshape(T + 1, B, heads)
        head_rewards = batch["rewards"] @ torch.tensor(self.case["head_weights"])
        targets = n_step_targets(values.detach(), head_rewards, batch["discounts"], valid)
        real = [(s, b) for s in range(T) for b in range(B) if valid[s, b] == 1.0]  # pair order t*B + b
        per_head = [
            0.5 * sum((values[s, b, c] - targets[s, b, c]) ** 2 for s, b in real) / len(real) for c in range(heads)
        ]
        value_mean = [sum(values[s, b, c].item() for s, b in real) / len(real) for c in range(heads)]
        self.critic_opt.zero_grad()
        sum(per_head).backward()
        self.critic_opt.step()

        # 2. Step 1 (D.2.1); objective k is head k here.
        eta = F.softplus(self.temperature_param) + 1e-8
        adv = [[(targets[s, b, k] - values[s, b, k]).item() for s, b in real] for k in range(len(self.case["epsilon"]))]
        pair_weights, temperature_loss, estep_kl = step_one(adv, eta, self.case["epsilon"])

        # 3. Step 2 (D.2.2, eq. 25) at the real states.
        obs = torch.stack([batch["observations"][s, b] for s, b in real])
        acts = [batch["actions"][s, b] for s, b in real]
        if self.gaussian:
            d = acts[0].shape[0]
            mean_o, std_o = gaussian(self.online, obs, d)
            with torch.no_grad():
                mean_t, std_t = gaussian(self.target, obs, d)
            nll, kl_mean, kl_cov = 0.0, 0.0, 0.0
            for i, a in enumerate(acts):
                log_mu = Normal(mean_o[i], std_t[i]).log_prob(a).sum()
                log_sigma = Normal(mean_t[i], std_o[i]).log_prob(a).sum()
                nll = nll - pair_weights[i] * (log_mu + log_sigma)
                old, kl = Normal(mean_t[i], std_t[i]), torch.distributions.kl_divergence
                kl_mean = kl_mean + kl(old, Normal(mean_o[i], std_t[i])).sum() / len(real)
                kl_cov = kl_cov + kl(old, Normal(mean_t[i], std_o[i])).sum() / len(real)
            alpha = F.softplus(self.alpha_param) + 1e-8
            policy_loss = nll + alpha[0].detach() * kl_mean + alpha[1].detach() * kl_cov
            alpha_loss = alpha[0] * (BETA_MEAN - kl_mean.detach()) + alpha[1] * (BETA_COV - kl_cov.detach())
            policy_kl = [kl_mean.item(), kl_cov.item()]
        else:
            log_o = torch.log_softmax(torso(self.online, obs), -1)
            with torch.no_grad():
                log_t = torch.log_softmax(torso(self.target, obs), -1)
            nll = -sum(pair_weights[i] * log_o[i, int(a)] for i, a in enumerate(acts))
            kl = sum((log_t[i].exp() * (log_t[i] - log_o[i])).sum() for i in range(len(real))) / len(real)
            alpha = F.softplus(self.alpha_param) + 1e-8
            policy_loss = nll + alpha[0].detach() * kl
            alpha_loss = alpha[0] * (BETA_CATEGORICAL - kl.detach())
            policy_kl = [kl.item()]
        self.policy_opt.zero_grad()
        self.dual_opt.zero_grad()
        (policy_loss + alpha_loss + temperature_loss).backward()
        self.policy_opt.step()
        self.dual_opt.step()
        with torch.no_grad():
            self.temperature_param.clamp_(min=-18.0)
            self.alpha_param.clamp_(min=-18.0)

        # 4. pi_old.
        self.steps += 1
        if self.steps % TARGET_PERIOD == 0:
            self.target = {k: v.detach().clone() for k, v in self.online.items() if k.startswith("policy.")}

        alpha = F.softplus(self.alpha_param) + 1e-8
        return {
            "critic_loss": [x.item() for x in per_head],
            "temperature": (F.softplus(self.temperature_param) + 1e-8).tolist(),
            "estep_kl": estep_kl,
            "q_mean": value_mean,
            "alpha": alpha.tolist(),
            "policy_kl": policy_kl,
            "alpha_by_part": [[a] for a in alpha.tolist()],
        }


def main():
    for case in [GAUSSIAN, CATEGORICAL]:
        gen = torch.Generator().manual_seed(29)
        params = initial_parameters(case, gen)
        initial = {k: t(v) for k, v in params.items()}
        learner = Learner(case, copy.deepcopy(params))
        steps = []
        for _ in range(STEPS):
            batch = make_batch(case, gen)
            stats = learner.step(batch)
            steps.append(
                {
                    "batch": {k: t(v) for k, v in batch.items()},
                    "stats": stats,
                    "parameters": {k: t(v) for k, v in learner.online.items()},
                }
            )
        payload = {"config": config(case), "dims": dims(case), "initial_parameters": initial, "steps": steps}
        write(f"vmpo_step_{case['name']}", payload)


if __name__ == "__main__":
    main()
