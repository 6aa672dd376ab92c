"""Expected values of the MO-V-MPO parts for agent/tests/golden.rs (appendix D), in
PyTorch float64 with explicit loops: top-k selection and the E-step (D.2.1), the T-step
value targets (D.1, eq. 21) and the policy fit (D.2.2, eq. 25). Run through
make_golden.py.
"""

import math

import torch
from make_golden_step import softplus_inv, t, write


def main():
    torch.set_default_dtype(torch.float64)
    # ---------------------------------------------------------------- MO-V-MPO step 1 (D.2.1)
    # N = 8 (s, a) pairs, K = 2 objectives. Pair 0 is ineligible (padding / an episode start)
    # and has the largest advantage of column 0, so it must not be selected. Eligible: 7, so
    # k = floor(0.5 * 7) = 3 per objective. Column 0's top three are 3.0, 1.0, 1.0 (a tie
    # inside the top k); column 1's are 2.0, 1.2, 0.5 with two more 0.5s tied at the
    # threshold, so 5 pairs are selected (selection uses >=, as rlax does).
    adv = torch.tensor(
        [
            [9.0, 0.3],
            [3.0, -1.0],
            [1.0, 0.5],
            [1.0, 2.0],
            [-2.0, 0.5],
            [0.5, 1.2],
            [-0.5, 0.5],
            [0.0, -3.0],
        ]
    )
    eligible = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
    eta_values = [0.8, 1.5]
    eps = [0.1, 0.02]
    frac = 0.5
    N, K = adv.shape
    n_el = int(sum(eligible))
    k_top = max(1, math.floor(frac * n_el))
    selected = torch.zeros(N, K)
    for k in range(K):
        ranked = sorted((adv[i, k].item() for i in range(N) if eligible[i] == 1.0), reverse=True)
        threshold = ranked[k_top - 1]
        for i in range(N):
            if eligible[i] == 1.0 and adv[i, k].item() >= threshold:
                selected[i, k] = 1.0
    weights = torch.zeros(N, K)
    for k in range(K):
        S = [i for i in range(N) if selected[i, k] == 1.0]
        z = sum(math.exp(adv[i, k].item() / eta_values[k]) for i in S)
        for i in S:
            weights[i, k] = math.exp(adv[i, k].item() / eta_values[k]) / z
    param = torch.tensor([softplus_inv(v) for v in eta_values], requires_grad=True)
    eta = torch.nn.functional.softplus(param) + 1e-8
    loss = 0.0
    for k in range(K):
        S = [i for i in range(N) if selected[i, k] == 1.0]
        # eq. 24 with the expectation under p_old replaced by the mean over the selected pairs
        mean_exp = sum(torch.exp(adv[i, k] / eta[k]) for i in S) / len(S)
        loss = loss + eta[k] * (eps[k] + torch.log(mean_exp))
    loss.backward()
    # KL(q_k || p_old) with p_old uniform (1 / n_el) over the eligible pairs
    kl = [
        sum(weights[i, k].item() * math.log(weights[i, k].item() * n_el) for i in range(N) if weights[i, k] > 0)
        for k in range(K)
    ]
    write(
        "vmpo_estep",
        {
            "advantages": t(adv),
            "eligible": eligible,
            "temperature": eta_values,
            "temperature_param": param.detach().tolist(),
            "epsilon": eps,
            "fraction": frac,
            "selected": t(selected),
            "weights": t(weights),
            "temperature_loss": loss.item(),
            "grad_temperature_param": param.grad.tolist(),
            "kl": kl,
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
