"""Straightforward PyTorch implementation of the same MO-MPO learner step as
`cargo bench -p agent --bench learner_step`, for a side-by-side comparison.

Same shapes and work: obs 67, act 21, B = 512 snippets of T = 8, M = 20, policy
(400, 400, 300), critic (500, 500, 400), K = 2 (task critic + closed-form action norm).
Target policy on (T+1)B states with M samples each; target critic on all (T+1)B*M pairs
(concatenated [obs, action] input); target critic on the T*B taken pairs; Retrace;
online critic regression + Adam; E-step with temperature duals; decoupled M-step with
alpha duals; Adam on the policy and the duals. Median of 20 steps after 3 warm-up steps.

Run: .venv/bin/python agent/benches/learner_step_torch.py [--threads N]  (prints its figure
last). `cargo bench -p agent --bench learner_step` runs it with `--rounds R --steps S`:
after warming up it prints `ready`, then for each line on stdin it times S steps and
prints `round_ms_median=<ms>`, so that the Rust and PyTorch steps alternate in rounds
and each round's ratio compares the two under the same load on the machine.
"""

import math
import os
import statistics
import sys
import time

import torch
from torch import nn
from torch.nn import functional as F

OBS, ACT, B, T, M = 67, 21, 512, 8, 20
GAMMA, EPS = 0.99, torch.tensor([0.1, 0.05])
BETA_MU, BETA_SIGMA, MIN_STD = 5e-3, 1e-6, 1e-4


def torso(inp, sizes):
    layers = [nn.Linear(inp, sizes[0]), nn.LayerNorm(sizes[0]), nn.Tanh()]
    for a, b in zip(sizes, sizes[1:]):
        layers += [nn.Linear(a, b), nn.ELU()]
    return layers


class Policy(nn.Module):
    def __init__(self):
        super().__init__()
        self.net = nn.Sequential(*torso(OBS, [400, 400, 300]), nn.Linear(300, 2 * ACT))

    def forward(self, obs):
        mean, raw = self.net(obs).chunk(2, -1)
        return mean, F.softplus(raw) + MIN_STD


class Critic(nn.Module):
    def __init__(self):
        super().__init__()
        self.net = nn.Sequential(*torso(OBS + ACT, [500, 500, 400]), nn.Linear(400, 1))

    def forward(self, obs, act):
        return self.net(torch.cat([obs, act], -1))


def log_prob(mean, std, a):
    return (-0.5 * ((a - mean) / std) ** 2 - std.log() - 0.5 * math.log(2 * math.pi)).sum(-1)


def arg(name, default):
    return int(sys.argv[sys.argv.index(name) + 1]) if name in sys.argv else default


def main():
    torch.set_num_threads(arg("--threads", os.cpu_count()))
    torch.manual_seed(0)
    policy, critic = Policy(), Critic()
    target_policy, target_critic = Policy(), Critic()
    target_policy.load_state_dict(policy.state_dict())
    target_critic.load_state_dict(critic.state_dict())
    pol_opt = torch.optim.Adam(policy.parameters(), lr=2e-4, eps=1e-8)
    crit_opt = torch.optim.Adam(critic.parameters(), lr=2e-4, eps=1e-8)

    def inv(v):
        return math.log(math.expm1(v))

    temp_param = torch.tensor([inv(1.0)] * 2, requires_grad=True)
    alpha_param = torch.tensor([inv(1.0), inv(10.0)], requires_grad=True)
    dual_opt = torch.optim.Adam([temp_param, alpha_param], lr=1e-2)

    obs = torch.randn(T + 1, B, OBS)
    actions = torch.randn(T, B, ACT).clamp(-1, 1)
    rewards = torch.randn(T, B, 2)
    discounts = torch.ones(T, B)
    behaviour_lp = torch.randn(T, B) - 20.0

    def step():
        n = (T + 1) * B
        obs_all = obs.reshape(n, OBS)
        obs_taken = obs_all[: T * B]
        act_taken = actions.reshape(T * B, ACT)
        with torch.no_grad():
            mean_t, std_t = target_policy(obs_all)
            samples = mean_t + std_t * torch.randn(M, n, ACT)
            q_samples = target_critic(obs_all.expand(M, n, OBS), samples).squeeze(-1)  # [M, N]
            v_next = q_samples.mean(0).reshape(T + 1, B)[1:]
            q_taken = target_critic(obs_taken, act_taken).squeeze(-1).reshape(T, B)
            lp = log_prob(mean_t[: T * B], std_t[: T * B], act_taken).reshape(T, B)
            c = (lp - behaviour_lp).exp().clamp(max=1.0)
            delta = rewards[..., 0] + GAMMA * discounts * v_next - q_taken
            adv = [delta[T - 1]]
            for t in range(T - 2, -1, -1):
                adv.append(delta[t] + GAMMA * discounts[t] * c[t + 1] * adv[-1])
            targets = q_taken + torch.stack(adv[::-1])
        q = critic(obs_taken, act_taken).squeeze(-1)
        crit_loss = 0.5 * (q - targets.reshape(-1)).pow(2).mean()
        crit_opt.zero_grad()
        crit_loss.backward()
        crit_opt.step()

        # E-step
        q_all = torch.stack([q_samples, -samples.norm(dim=-1)], -1)  # [M, N, K]
        eta = F.softplus(temp_param) + 1e-8
        scaled = q_all / eta
        weights = scaled.detach().softmax(0)
        temp_loss = (eta * (EPS + torch.logsumexp(scaled, 0).mean(0) - math.log(M))).sum()
        # M-step
        mean_o, std_o = policy(obs_all)
        w = weights.sum(-1)
        ll = log_prob(mean_o, std_t, samples) + log_prob(mean_t, std_o, samples)
        nll = -(w * ll).sum(0).mean()
        kl_mu = ((mean_t - mean_o) ** 2 / (2 * std_t**2)).sum(-1).mean()
        kl_sigma = ((std_o / std_t).log() + std_t**2 / (2 * std_o**2) - 0.5).sum(-1).mean()
        alpha = F.softplus(alpha_param) + 1e-8
        loss = nll + alpha[0].detach() * kl_mu + alpha[1].detach() * kl_sigma
        loss = loss + alpha[0] * (BETA_MU - kl_mu.detach()) + alpha[1] * (BETA_SIGMA - kl_sigma.detach())
        pol_opt.zero_grad()
        dual_opt.zero_grad()
        (loss + temp_loss).backward()
        pol_opt.step()
        dual_opt.step()
        with torch.no_grad():
            temp_param.clamp_(min=-18)
            alpha_param.clamp_(min=-18)

    def timed(steps):
        times = []
        for _ in range(steps):
            start = time.perf_counter()
            step()
            times.append((time.perf_counter() - start) * 1e3)
        return times

    for _ in range(3):
        step()
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}", flush=True)
    steps, rounds = arg("--steps", 20), arg("--rounds", None)
    if rounds is None:
        times = timed(steps)
    else:
        print("ready", flush=True)
        times = []
        for _ in range(rounds):
            sys.stdin.readline()
            round_times = timed(steps)
            print(f"round_ms_median={statistics.median(round_times):.2f}", flush=True)
            times += round_times
    print(f"learner_step_ms_median={statistics.median(times):.1f}")


if __name__ == "__main__":
    main()
