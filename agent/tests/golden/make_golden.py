"""Expected values for agent/tests/golden.rs, computed independently in PyTorch (float64).

Run from the repo root:  .venv/bin/python agent/tests/golden/make_golden.py
It rewrites agent/tests/golden/*.json: the MPO parts here, the MO-V-MPO parts through
make_golden_vmpo_parts.py, the whole steps through make_golden_step.py,
make_golden_vmpo_step.py and make_golden_conditioned_step.py.
The formulas follow the paper (Abdolmaleki et al. 2020, appendix C.2, C.3, D, E.1) directly, with explicit loops and torch.distributions
where possible, not the vectorised forms used by the Rust code.
"""

import math

import make_golden_step
import make_golden_vmpo_parts
import make_golden_vmpo_step
import torch
from make_golden_step import OUT, softplus_inv, t, write

torch.set_default_dtype(torch.float64)


# ---------------------------------------------------------------- E-step, sampled
# q[j, i, k]: M=4 samples, B=2 states, K=2 objectives.
q = torch.tensor(
    [
        [[1.0, -3.0], [0.5, 10.0]],
        [[2.0, -1.0], [-0.5, 12.0]],
        [[0.0, -2.5], [1.5, 11.0]],
        [[3.0, -0.5], [0.0, 9.0]],
    ]
)
eta_values = [0.7, 2.0]
eps = [0.1, 0.05]
M, B, K = q.shape
weights = torch.zeros_like(q)
for k in range(K):
    for i in range(B):
        z = [q[j, i, k].item() / eta_values[k] for j in range(M)]
        zmax = max(z)
        e = [math.exp(v - zmax) for v in z]
        for j in range(M):
            weights[j, i, k] = e[j] / sum(e)
param = torch.tensor([softplus_inv(v) for v in eta_values], requires_grad=True)
eta = torch.nn.functional.softplus(param) + 1e-8
loss = 0.0
for k in range(K):
    # eq. 34 with the integral over pi_old replaced by the mean over the M samples
    per_state = [torch.log(torch.mean(torch.exp(q[:, i, k] / eta[k]))) for i in range(B)]
    loss = loss + eta[k] * (eps[k] + sum(per_state) / B)
loss.backward()
write(
    "estep_sampled",
    {
        "q": t(q),
        "temperature": eta_values,
        "temperature_param": param.detach().tolist(),
        "epsilon": eps,
        "weights": t(weights),
        "loss": loss.item(),
        "grad_param": param.grad.tolist(),
    },
)

# ---------------------------------------------------------------- E-step, categorical
# q[a, i, k]: A=3 actions, B=2 states, K=2; prior pi_old[i, a].
qc = torch.tensor(
    [
        [[1.0, 0.0], [-1.0, 5.0]],
        [[0.0, 2.0], [2.0, 4.0]],
        [[-2.0, 1.0], [0.5, 4.5]],
    ]
)
prior = torch.tensor([[0.2, 0.5, 0.3], [0.6, 0.1, 0.3]])
eta_c = [0.5, 1.5]
eps_c = [0.2, 0.01]
A = qc.shape[0]
wc = torch.zeros_like(qc)
for k in range(K):
    for i in range(B):
        unnorm = [prior[i, a].item() * math.exp(qc[a, i, k].item() / eta_c[k]) for a in range(A)]
        for a in range(A):
            wc[a, i, k] = unnorm[a] / sum(unnorm)
param_c = torch.tensor([softplus_inv(v) for v in eta_c], requires_grad=True)
eta_t = torch.nn.functional.softplus(param_c) + 1e-8
loss_c = 0.0
for k in range(K):
    per_state = [torch.log(sum(prior[i, a] * torch.exp(qc[a, i, k] / eta_t[k]) for a in range(A))) for i in range(B)]
    loss_c = loss_c + eta_t[k] * (eps_c[k] + sum(per_state) / B)
loss_c.backward()
write(
    "estep_categorical",
    {
        "q": t(qc),
        "prior": t(prior),
        "temperature": eta_c,
        "temperature_param": param_c.detach().tolist(),
        "epsilon": eps_c,
        "weights": t(wc),
        "loss": loss_c.item(),
        "grad_param": param_c.grad.tolist(),
    },
)

# ---------------------------------------------------------------- Gaussian M-step
N = torch.distributions.Normal
mu_o = torch.tensor([[0.1, -0.2, 0.3], [0.0, 0.5, -0.4]], requires_grad=True)
sd_o = torch.tensor([[0.5, 0.8, 1.1], [0.3, 0.6, 0.9]], requires_grad=True)
mu_t = torch.tensor([[0.0, -0.1, 0.5], [0.2, 0.4, -0.5]])
sd_t = torch.tensor([[0.6, 0.7, 1.0], [0.35, 0.5, 1.0]])
actions = torch.tensor(
    [
        [[0.2, -0.3, 0.1], [0.1, 0.6, -0.2]],
        [[-0.5, 0.0, 1.2], [0.4, 0.3, -0.9]],
        [[0.0, 0.4, 0.5], [-0.1, 0.5, -0.5]],
    ]
)  # [M=3, B=2, D=3]
w = torch.tensor([[0.5, 1.2], [1.0, 0.3], [0.5, 0.5]])  # [M, B], sums to K=2 per state
alpha_mu = torch.tensor(1.3, requires_grad=True)
alpha_sigma = torch.tensor(10.0, requires_grad=True)
beta_mu, beta_sigma = 5e-3, 1e-5
log_prob_online = N(mu_o, sd_o).log_prob(actions).sum(-1)  # [M, B]
ll = N(mu_o, sd_t).log_prob(actions).sum(-1) + N(mu_t, sd_o).log_prob(actions).sum(-1)
nll = -(w * ll).sum(0).mean()
kl_mu = torch.distributions.kl_divergence(N(mu_t, sd_t), N(mu_o, sd_t)).sum(-1).mean()
kl_sigma = torch.distributions.kl_divergence(N(mu_t, sd_t), N(mu_t, sd_o)).sum(-1).mean()
policy_loss = nll + alpha_mu.detach() * kl_mu + alpha_sigma.detach() * kl_sigma
alpha_loss = alpha_mu * (beta_mu - kl_mu.detach()) + alpha_sigma * (beta_sigma - kl_sigma.detach())
(policy_loss + alpha_loss).backward()
write(
    "mstep_gaussian",
    {
        "online_mean": t(mu_o),
        "online_std": t(sd_o),
        "target_mean": t(mu_t),
        "target_std": t(sd_t),
        "actions": t(actions),
        "weights": t(w),
        "alpha_mean": 1.3,
        "alpha_cov": 10.0,
        "beta_mean": beta_mu,
        "beta_cov": beta_sigma,
        "log_prob_online": t(log_prob_online),
        "kl_mean": kl_mu.item(),
        "kl_cov": kl_sigma.item(),
        "policy_loss": policy_loss.item(),
        "alpha_loss": alpha_loss.item(),
        "grad_alpha_mean": alpha_mu.grad.item(),
        "grad_alpha_cov": alpha_sigma.grad.item(),
        "grad_online_mean": t(mu_o.grad),
        "grad_online_std": t(sd_o.grad),
    },
)

# ---------------------------------------------------------------- Gaussian M-step, per dimension
# Acme's per_dim_constraining: the same policies, samples and weights, but each action
# dimension's KL (averaged over states) is bounded by beta on its own, with one alpha_mu
# and one alpha_Sigma per dimension: sum_d sg(alpha_d) KL_d in the policy loss and
# sum_d alpha_d (beta - sg(KL_d)) in the multipliers' loss.
mu_o.grad, sd_o.grad = None, None
alpha_mu_d = torch.tensor([1.3, 0.4, 2.0], requires_grad=True)
alpha_sigma_d = torch.tensor([10.0, 3.0, 0.5], requires_grad=True)
nll = -(w * (N(mu_o, sd_t).log_prob(actions).sum(-1) + N(mu_t, sd_o).log_prob(actions).sum(-1))).sum(0).mean()
kl_mu_d = torch.distributions.kl_divergence(N(mu_t, sd_t), N(mu_o, sd_t)).mean(0)  # [D]
kl_sigma_d = torch.distributions.kl_divergence(N(mu_t, sd_t), N(mu_t, sd_o)).mean(0)  # [D]
policy_loss = nll
alpha_loss = 0.0
for d in range(3):
    policy_loss = policy_loss + alpha_mu_d[d].detach() * kl_mu_d[d] + alpha_sigma_d[d].detach() * kl_sigma_d[d]
    alpha_loss = alpha_loss + alpha_mu_d[d] * (beta_mu - kl_mu_d[d].detach())
    alpha_loss = alpha_loss + alpha_sigma_d[d] * (beta_sigma - kl_sigma_d[d].detach())
(policy_loss + alpha_loss).backward()
write(
    "mstep_gaussian_per_dimension",
    {
        "online_mean": t(mu_o),
        "online_std": t(sd_o),
        "target_mean": t(mu_t),
        "target_std": t(sd_t),
        "actions": t(actions),
        "weights": t(w),
        "alpha_mean": alpha_mu_d.tolist(),
        "alpha_cov": alpha_sigma_d.tolist(),
        "beta_mean": beta_mu,
        "beta_cov": beta_sigma,
        "kl_mean": kl_mu_d.tolist(),
        "kl_cov": kl_sigma_d.tolist(),
        "policy_loss": policy_loss.item(),
        "alpha_loss": alpha_loss.item(),
        "grad_alpha_mean": alpha_mu_d.grad.tolist(),
        "grad_alpha_cov": alpha_sigma_d.grad.tolist(),
        "grad_online_mean": t(mu_o.grad),
        "grad_online_std": t(sd_o.grad),
    },
)

# ---------------------------------------------------------------- categorical M-step
logits_o = torch.tensor([[0.1, 0.5, -0.3], [1.0, -1.0, 0.0]], requires_grad=True)
logits_t = torch.tensor([[0.0, 0.6, -0.2], [0.8, -0.9, 0.1]])
wcat = torch.tensor([[0.3, 1.0], [1.2, 0.4], [0.5, 0.6]])  # [A, B]
alpha_c = torch.tensor(2.0, requires_grad=True)
beta_c = 1e-3
p_o = torch.distributions.Categorical(logits=logits_o)
p_t = torch.distributions.Categorical(logits=logits_t)
nll_c = -sum((wcat[a] * p_o.log_prob(torch.full((2,), a))).mean() for a in range(3))
kl_c = torch.distributions.kl_divergence(p_t, p_o).mean()
policy_c = nll_c + alpha_c.detach() * kl_c
alpha_loss_c = alpha_c * (beta_c - kl_c.detach())
(policy_c + alpha_loss_c).backward()
write(
    "mstep_categorical",
    {
        "online_logits": t(logits_o),
        "target_logits": t(logits_t),
        "weights": t(wcat),
        "alpha": 2.0,
        "beta": beta_c,
        "policy_loss": policy_c.item(),
        "alpha_loss": alpha_loss_c.item(),
        "kl": kl_c.item(),
        "grad_alpha": alpha_c.grad.item(),
        "grad_online_logits": t(logits_o.grad),
    },
)

# ---------------------------------------------------------------- Retrace (C.2)
# T=4 steps, B=2 snippets, C=2 critics. Snippet 0 terminates after step 1 (d_1 = 0) and
# continues into a new episode; snippet 1 has no terminal. Several c_z < 1.
T, Bs, C = 4, 2, 2
gamma = 0.9
q_taken = torch.tensor(
    [
        [[1.0, 0.5], [2.0, -1.0]],
        [[0.5, 0.0], [1.5, -0.5]],
        [[3.0, 1.0], [1.0, 0.0]],
        [[2.5, 0.5], [0.5, 0.2]],
    ]
)
v_next = torch.tensor(
    [
        [[0.8, 0.2], [1.8, -0.8]],
        [[9.0, 9.0], [1.2, -0.2]],  # ignored for snippet 0 (terminal)
        [[2.0, 0.8], [0.7, 0.1]],
        [[1.0, 0.3], [0.4, 0.4]],
    ]
)
rewards = torch.tensor(
    [
        [[1.0, -0.1], [0.0, -0.2]],
        [[2.0, -0.3], [1.0, 0.0]],
        [[0.5, -0.2], [0.5, -0.1]],
        [[1.0, 0.0], [0.2, -0.4]],
    ]
)
discounts = torch.tensor([[1.0, 1.0], [0.0, 1.0], [1.0, 1.0], [1.0, 1.0]])
target_lp = torch.tensor([[-1.0, -0.5], [-0.2, -1.5], [-2.0, -0.3], [-0.7, -0.7]])
behaviour_lp = torch.tensor([[-0.8, -0.6], [-0.9, -1.0], [-1.0, -0.3], [-1.5, -0.2]])
c = [[min(1.0, math.exp(target_lp[z, b] - behaviour_lp[z, b])) for b in range(Bs)] for z in range(T)]
q_ret = torch.zeros(T, Bs, C)
for b in range(Bs):
    for k in range(C):
        for s in range(T):
            total = q_taken[s, b, k].item()
            for j in range(s, T):
                trace = gamma ** (j - s)
                for z in range(s + 1, j + 1):
                    trace *= c[z][b]
                for z in range(s, j):
                    trace *= discounts[z, b].item()  # the trace stops at a terminal
                delta = rewards[j, b, k] + gamma * discounts[j, b] * v_next[j, b, k] - q_taken[j, b, k]
                total += trace * delta.item()
            q_ret[s, b, k] = total
write(
    "retrace",
    {
        "gamma": gamma,
        "q_taken": t(q_taken),
        "v_next": t(v_next),
        "rewards": t(rewards),
        "discounts": t(discounts),
        "target_log_probs": t(target_lp),
        "behaviour_log_probs": t(behaviour_lp),
        "importance": t(torch.tensor(c)),
        "targets": t(q_ret),
    },
)

make_golden_vmpo_parts.main()
make_golden_step.main()
make_golden_vmpo_step.main()
# Imported only now: it widens make_golden_step's observation for the conditioned steps.
import make_golden_conditioned_step  # noqa: E402

make_golden_conditioned_step.main()
print("wrote", sorted(p.name for p in OUT.glob("*.json")))
