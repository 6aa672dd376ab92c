"""A CleanRL-style PPO loop (ppo_continuous_action.py, cut down) learns remote pendulum
through one RemoteVectorEnv session of 8 instances under gymnasium's vector wrappers.

The reward is the `task` objective (Pendulum-v1's reward), picked by TransformReward and
counted by RecordEpisodeStatistics. 30 iterations of 8 x 200 steps (48,000 env steps)
take about 11 s on one CPU thread; on seeds 0-2 the mean episodic return went from about
-1200 in the first three iterations to -200..-350 in the last three, so the test asks for
a gain of 400, well inside what every seed reached. Seeded: the server seeds the
instances and torch the policy, on one thread.

The loop runs in a child process (this file as a script): torch.optim imports triton,
whose LLVM crashed (SIGSEGV) a pytest process that had loaded MuJoCo's GL libraries for
the render tests before it.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import torch
from conftest import running_server, server_env
from gymnasium.wrappers import vector as wrappers
from torch import nn

from env_server.client import RemoteVectorEnv

SEED = 0
NUM_ENVS = 8
NUM_STEPS = 200  # per env and iteration: one pendulum episode
ITERATIONS = 30
GAMMA = 0.9
GAE_LAMBDA = 0.95
UPDATE_EPOCHS = 10
MINIBATCHES = 8
CLIP = 0.2
LEARNING_RATE = 1e-3
REWARD_SCALE = 0.1  # pendulum's reward reaches -16 per step; smaller targets suit the critic


def layer(inputs: int, outputs: int, std: float = np.sqrt(2)) -> nn.Linear:
    linear = nn.Linear(inputs, outputs)
    nn.init.orthogonal_(linear.weight, std)
    nn.init.zeros_(linear.bias)
    return linear


class Agent(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int) -> None:
        super().__init__()
        self.critic = nn.Sequential(layer(obs_dim, 64), nn.Tanh(), layer(64, 64), nn.Tanh(), layer(64, 1, 1.0))
        self.actor_mean = nn.Sequential(
            layer(obs_dim, 64), nn.Tanh(), layer(64, 64), nn.Tanh(), layer(64, act_dim, 0.01)
        )
        self.actor_logstd = nn.Parameter(torch.zeros(1, act_dim))

    def action_and_value(self, obs: torch.Tensor, action: torch.Tensor | None = None):
        mean = self.actor_mean(obs)
        dist = torch.distributions.Normal(mean, self.actor_logstd.expand_as(mean).exp())
        if action is None:
            action = dist.sample()
        return action, dist.log_prob(action).sum(1), self.critic(obs).flatten()


def train(address: str) -> list[float]:
    """The mean episodic return of each iteration."""
    env = RemoteVectorEnv(address, "pendulum", NUM_ENVS, seed=SEED)
    envs = wrappers.RecordEpisodeStatistics(wrappers.TransformReward(env, lambda r: r[:, 0]))
    obs_dim, act_dim = env.single_observation_space.shape[0], env.single_action_space.shape[0]
    low, high = env.single_action_space.low, env.single_action_space.high
    agent = Agent(obs_dim, act_dim)
    optimizer = torch.optim.Adam(agent.parameters(), lr=LEARNING_RATE, eps=1e-5)

    obs = torch.zeros(NUM_STEPS, NUM_ENVS, obs_dim)
    actions = torch.zeros(NUM_STEPS, NUM_ENVS, act_dim)
    logprobs, rewards, dones, values = (torch.zeros(NUM_STEPS, NUM_ENVS) for _ in range(4))
    next_obs = torch.tensor(envs.reset(seed=SEED)[0])
    next_done = torch.zeros(NUM_ENVS)
    mean_returns = []
    try:
        for _ in range(ITERATIONS):
            episode_returns = []
            for step in range(NUM_STEPS):
                obs[step], dones[step] = next_obs, next_done
                with torch.no_grad():
                    action, logprob, value = agent.action_and_value(next_obs)
                actions[step], logprobs[step], values[step] = action, logprob, value
                # SAME_STEP autoreset: next_obs already starts the next episode of an ended env.
                o, reward, terminated, truncated, infos = envs.step(np.clip(action.numpy(), low, high))
                rewards[step] = torch.tensor(reward) * REWARD_SCALE
                next_obs, next_done = torch.tensor(o), torch.tensor(terminated | truncated, dtype=torch.float32)
                if "episode" in infos:
                    episode_returns += infos["episode"]["r"][infos["_episode"]].tolist()
            mean_returns.append(float(np.mean(episode_returns)))

            # ALGO LOGIC: generalized advantage estimation
            with torch.no_grad():
                next_value = agent.critic(next_obs).flatten()
                advantages = torch.zeros_like(rewards)
                last = torch.zeros(NUM_ENVS)
                for t in reversed(range(NUM_STEPS)):
                    not_done = 1.0 - (next_done if t == NUM_STEPS - 1 else dones[t + 1])
                    following = next_value if t == NUM_STEPS - 1 else values[t + 1]
                    delta = rewards[t] + GAMMA * following * not_done - values[t]
                    advantages[t] = last = delta + GAMMA * GAE_LAMBDA * not_done * last
                returns = advantages + values

            # ALGO LOGIC: clipped surrogate and value loss over minibatches
            b_obs, b_actions = obs.reshape(-1, obs_dim), actions.reshape(-1, act_dim)
            b_logprobs, b_advantages, b_returns = logprobs.reshape(-1), advantages.reshape(-1), returns.reshape(-1)
            size = len(b_obs) // MINIBATCHES
            for _ in range(UPDATE_EPOCHS):
                order = torch.randperm(len(b_obs))
                for start in range(0, len(b_obs), size):
                    mb = order[start : start + size]
                    _, new_logprob, new_value = agent.action_and_value(b_obs[mb], b_actions[mb])
                    ratio = (new_logprob - b_logprobs[mb]).exp()
                    adv = b_advantages[mb]
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                    pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - CLIP, 1 + CLIP)).mean()
                    v_loss = 0.5 * ((new_value - b_returns[mb]) ** 2).mean()
                    optimizer.zero_grad()
                    (pg_loss + 0.5 * v_loss).backward()
                    nn.utils.clip_grad_norm_(agent.parameters(), 0.5)
                    optimizer.step()
    finally:
        envs.close()
    return mean_returns


def test_ppo_improves_the_episodic_return_on_remote_pendulum() -> None:
    with running_server() as address:  # the default front, the one a user gets
        out = subprocess.run(
            [sys.executable, __file__, address], capture_output=True, text=True, env=server_env(), timeout=300
        )
    assert out.returncode == 0, out.stderr[-3000:]
    mean_returns = json.loads(out.stdout.splitlines()[-1])
    early, late = np.mean(mean_returns[:3]), np.mean(mean_returns[-3:])
    assert late > early + 400, f"mean episodic return {early:.0f} -> {late:.0f}: {np.round(mean_returns)}"


if __name__ == "__main__":
    torch.set_num_threads(1)
    torch.manual_seed(SEED)
    print(json.dumps(train(sys.argv[1])))
