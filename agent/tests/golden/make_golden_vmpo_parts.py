"""Expected values of the MO-V-MPO parts for agent/tests/golden.rs (appendix D), in
PyTorch float64 with explicit loops: top-k selection and the E-step (D.2.1) under every
rule of `vmpo.top_k`, the T-step value targets (D.1, eq. 21) and the policy fit (D.2.2,
eq. 25). Run through make_golden.py.
"""

import math

import torch
from make_golden_step import softplus_inv, t, write


def main():
    torch.set_default_dtype(torch.float64)
    # ---------------------------------------------------------------- MO-V-MPO step 1 (D.2.1)
    # N = 8 (s, a) pairs, K = 3 objectives. Pair 0 is ineligible (padding / an episode start)
    # and has the largest advantage of column 0, so it must never be selected. Eligible: 7, so
    # k = floor(0.5 * 7) = 3. Objective 2 has eps = 0: it is ignored by the joint score and gets
    # no dual gradient. Every rule of `vmpo.top_k` is computed, each from its definition:
    adv = torch.tensor(
        [
            [9.0, 0.3, 5.0],
            [3.0, -1.0, -2.0],
            [1.0, 0.5, 0.1],
            [1.0, 2.0, 3.0],
            [-2.0, 0.5, 1.0],
            [0.5, 1.2, -1.0],
            [-0.5, 0.5, 2.0],
            [0.0, -3.0, 0.5],
        ]
    )
    eligible = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
    eta_values = [0.8, 1.5, 0.6]
    eps = [0.1, 0.02, 0.0]
    frac = 0.5
    N, K = adv.shape
    rows = [i for i in range(N) if eligible[i] == 1.0]
    n_el = len(rows)
    k_top = max(1, math.floor(frac * n_el))
    active = [e > 0.0 for e in eps]

    def top(score):
        """The eligible pairs whose score is >= the k-th largest (ties in, as rlax)."""
        ranked = sorted((score[i] for i in rows), reverse=True)
        threshold = ranked[k_top - 1]
        # The float32 Rust side must select the same pairs.
        gap = min((abs(score[i] - threshold) for i in rows if score[i] != threshold), default=1.0)
        assert gap > 1e-4, f"scores too close to the top-k threshold ({gap})"
        return [i for i in rows if score[i] >= threshold]

    def softmax_over(pairs, logits):
        z = sum(math.exp(logits[i]) for i in pairs)
        return [math.exp(logits[i]) / z if i in pairs else 0.0 for i in range(N)]

    def tilt(k):
        return [adv[i, k].item() / eta_values[k] for i in range(N)]

    def uniform(pairs):
        return [1.0 / len(pairs) if i in pairs else 0.0 for i in range(N)]

    # joint: s_i = sum over active k of A_ki / eta_k, the log-density ratio of the product
    # p_old prod_k exp(A_k / eta_k); one selection S = top(s) for every objective.
    joint_score = [sum(adv[i, k].item() / eta_values[k] for k in range(K) if active[k]) for i in range(N)]
    joint_set = top(joint_score)
    per_objective_sets = [top([adv[i, k].item() for i in range(N)]) for k in range(K)]
    selections = {
        "joint": [joint_set] * K,
        "shared": [joint_set] * K,
        "per_objective": per_objective_sets,
        "duals_only": per_objective_sets,
    }

    def fit_weights(rule):
        """Eq. 25's weights per pair: one distribution for joint, K for the others."""
        if rule == "joint":
            # softmax_S(s): the product of the q_k on S, one distribution.
            return softmax_over(joint_set, joint_score)
        total = [0.0] * N
        for k in range(K):
            if rule == "shared":
                q = softmax_over(joint_set, tilt(k)) if active[k] else uniform(joint_set)
            elif rule == "per_objective":
                q = softmax_over(per_objective_sets[k], tilt(k)) if active[k] else uniform(rows)
            else:  # duals_only: the fit weights every eligible pair
                q = softmax_over(rows, tilt(k)) if active[k] else uniform(rows)
            total = [x + y for x, y in zip(total, q)]
        return total

    cases = {}
    for rule, sets in selections.items():
        param = torch.tensor([softplus_inv(v) for v in eta_values], requires_grad=True)
        eta = torch.nn.functional.softplus(param) + 1e-8
        loss = 0.0
        for k in range(K):
            if active[k]:
                # eq. 24 with the expectation under p_old replaced by the mean over S_k
                mean_exp = sum(torch.exp(adv[i, k] / eta[k]) for i in sets[k]) / len(sets[k])
                loss = loss + eta[k] * (eps[k] + torch.log(mean_exp))
        loss.backward()
        # KL(q_k || p_old), q_k = softmax over S_k of A_k / eta_k, p_old uniform over the
        # eligible pairs; 0 for eps_k = 0.
        kl = []
        for k in range(K):
            q = softmax_over(sets[k], tilt(k))
            kl.append(sum(w * math.log(w * n_el) for w in q if w > 0.0) if active[k] else 0.0)
        selected = torch.zeros(N, K)
        for k in range(K):
            for i in sets[k]:
                selected[i, k] = 1.0
        cases[rule] = {
            "selected": t(selected),
            "fit_weights": fit_weights(rule),
            "temperature_loss": loss.item(),
            "grad_temperature_param": param.grad.tolist(),
            "kl": kl,
        }
    write(
        "vmpo_estep",
        {
            "advantages": t(adv),
            "eligible": eligible,
            "temperature": eta_values,
            "temperature_param": [softplus_inv(v) for v in eta_values],
            "epsilon": eps,
            "fraction": frac,
            "rules": cases,
        },
    )

    # ---------------------------------------------------------------- T-step targets (D.1, eq. 21)
    # T = 4 steps, B = 3 unrolls, C = 2 heads, gamma 0.95. Unroll 0: all real, no terminal.
    # Unroll 1: terminal at step 1, padding after. Unroll 2: truncated at step 2 (discount 1),
    # padding at step 3. G_t = sum_{l=t}^{end-1} gamma^(l-t) r_l + gamma^(end-t) V(s_end) with
    # `end` the unroll's end or the first padding step, cut at a terminal.
    gamma = 0.95
    T, Bs, C = 4, 3, 2
    torch.manual_seed(5)
    rewards = torch.round(torch.randn(T, Bs, C) * 10) / 10
    values = torch.round(torch.randn(T + 1, Bs, C) * 10) / 10
    discounts = torch.ones(T, Bs)
    valid = torch.ones(T, Bs)
    discounts[1, 1] = 0.0
    valid[2:, 1] = 0.0
    discounts[2:, 1] = 0.0
    valid[3, 2] = 0.0
    discounts[3, 2] = 0.0
    rewards[valid == 0.0] = 0.0
    targets = torch.zeros(T, Bs, C)
    for b in range(Bs):
        end = next((z for z in range(T) if valid[z, b] == 0.0), T)
        for s in range(end):
            for c_ in range(C):
                g, scale = 0.0, 1.0
                for z in range(s, end):
                    g += scale * rewards[z, b, c_].item()
                    scale *= gamma * discounts[z, b].item()
                g += scale * values[end, b, c_].item()
                targets[s, b, c_] = g
    write(
        "vmpo_targets",
        {
            "gamma": gamma,
            "rewards": t(rewards),
            "values": t(values),
            "discounts": t(discounts),
            "valid": t(valid),
            "targets": t(targets),
            "valid_mask": t(valid),
        },
    )

    # ---------------------------------------------------------------- MO-V-MPO step 2 (D.2.2, eq. 25)
    # N = 3 pairs, D = 2: -sum_i w_i [log pi_mu(a_i|s_i) + log pi_Sigma(a_i|s_i)] with the decoupled
    # policies of eqs. 18-20, plus the KL multiplier terms with Table 5's betas.
    om = torch.tensor([[0.1, -0.2], [0.0, 0.5], [0.3, 0.3]], requires_grad=True)
    os_ = torch.tensor([[0.5, 0.9], [1.1, 0.7], [0.6, 0.6]], requires_grad=True)
    tm = torch.tensor([[0.0, -0.1], [0.2, 0.4], [0.3, 0.1]])
    ts = torch.tensor([[0.6, 0.8], [1.0, 0.9], [0.5, 0.7]])
    acts = torch.tensor([[0.4, -0.6], [-0.3, 1.0], [0.2, 0.0]])
    w = torch.tensor([0.5, 0.2, 0.3])
    a_mu = torch.tensor(1.3, requires_grad=True)
    a_sig = torch.tensor(0.7, requires_grad=True)
    beta_mu, beta_sig = 0.1, 1e-5
    Nrm = torch.distributions.Normal
    nll = 0.0
    for i in range(3):
        lp_mu = Nrm(om[i], ts[i]).log_prob(acts[i]).sum()
        lp_sig = Nrm(tm[i], os_[i]).log_prob(acts[i]).sum()
        nll = nll - w[i] * (lp_mu + lp_sig)
    kl_mu = sum(torch.distributions.kl_divergence(Nrm(tm[i], ts[i]), Nrm(om[i], ts[i])).sum() for i in range(3)) / 3
    kl_sig = sum(torch.distributions.kl_divergence(Nrm(tm[i], ts[i]), Nrm(tm[i], os_[i])).sum() for i in range(3)) / 3
    policy_loss = nll + a_mu.detach() * kl_mu + a_sig.detach() * kl_sig
    alpha_loss = a_mu * (beta_mu - kl_mu.detach()) + a_sig * (beta_sig - kl_sig.detach())
    (policy_loss + alpha_loss).backward()
    write(
        "vmpo_mstep",
        {
            "online_mean": t(om),
            "online_std": t(os_),
            "target_mean": t(tm),
            "target_std": t(ts),
            "actions": t(acts),
            "weights": w.tolist(),
            "alpha_mean": a_mu.item(),
            "alpha_cov": a_sig.item(),
            "beta_mean": beta_mu,
            "beta_cov": beta_sig,
            "policy_loss": policy_loss.item(),
            "alpha_loss": alpha_loss.item(),
            "kl_mean": kl_mu.item(),
            "kl_cov": kl_sig.item(),
            "grad_alpha_mean": a_mu.grad.item(),
            "grad_alpha_cov": a_sig.grad.item(),
            "grad_online_mean": t(om.grad),
            "grad_online_std": t(os_.grad),
        },
    )
