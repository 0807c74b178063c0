"""The MLP Q as fitted before 77d1c1c (gradient steps only) and as it is now, on the transfer setting.

The paper's transfer setting (section 4, Figure 5): 25,000 random source transitions with their rewards
discarded, then 1,000 online transitions on the target task (``transfer_run``); run r targets task r % 25
with seed r, the same runs for every method (common random numbers: the same source transitions and env
seeds, and the same hidden layers at the start for both MLPs). Methods:

- MLP, gradient-only fit: ``MlpPolicy`` refitted as before 77d1c1c (``gradient_only_fit_mlp_fqi`` below,
  a copy of that ``fit_mlp_fqi``, on that ``make_q_network``'s networks): every refit runs all of its 20
  fitted iterations, each 2 epochs of shuffled minibatches of 512 (2,000 Adam steps), with an Adam made
  anew at every refit;
- MLP: ``MlpPolicy`` as it is (``fit_mlp_fqi``): one Adam epoch on the hidden layers, Adam's state kept
  across refits, then linear FQI of the output layer on the hidden features until theta moves by less
  than ``fqi_tol`` (relative);
- linear: ``LinearPolicy``, the paper's Q, for reference.

Prints per method the seconds per run (wall, and CPU: other processes on the machine inflate the wall
time), the mean expected reward E[R_task(s_t)] over the 1,000 online transitions and over the last 500
with standard errors over the runs, and the refits per run; then the two MLPs on their common runs: the
ratio of their seconds per run and the paired differences of their rewards (± standard error). Each worker
runs one torch thread and one BLAS thread. The gradient-only fit takes ~2 minutes of CPU per run:
``--gradient-only-runs`` runs it on the first runs only. Usage::

    python benchmarks/bench_mlp.py --runs 24 --gradient-only-runs 24 --workers 2 [--cache runs/bench_mlp]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th

from sb3_trlsd import TRLSD
from sb3_trlsd.fit_rows import FitRows, TransitionRows
from sb3_trlsd.fqi import FQIResult, return_bounds
from sb3_trlsd.policies import MlpPolicy
from sb3_trlsd_lab.execution.jobs import run_jobs
from sb3_trlsd_lab.execution.runner import Method, RunRecord, transfer_run


def gradient_only_fit_mlp_fqi(
    inputs: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_inputs: np.ndarray,
    terminated: np.ndarray,
    *,
    network: th.nn.Module,
    gamma: float,
    iterations: int,
    epochs_per_iteration: int = 2,
    batch_size: int = 512,
    learning_rate: float = 1e-3,
) -> FQIResult:
    """``fit_mlp_fqi`` before 77d1c1c (its checks and generator argument left out; shuffled by torch's global
    generator, as ``MlpPolicy`` called it)."""
    device = next(network.parameters()).device
    x = th.as_tensor(inputs, dtype=th.float32, device=device)
    x_next = th.as_tensor(next_inputs, dtype=th.float32, device=device)
    a = th.as_tensor(np.asarray(actions, dtype=np.int64), device=device)
    r = th.as_tensor(rewards, dtype=th.float32, device=device)
    continues = th.as_tensor(~np.asarray(terminated, dtype=bool), dtype=th.float32, device=device)
    low, high = return_bounds(np.asarray(rewards, dtype=np.float64), gamma)
    optimizer = th.optim.Adam(network.parameters(), lr=learning_rate)

    def targets() -> th.Tensor:
        with th.no_grad():
            return r + gamma * continues * network(x_next).max(dim=1).values.clamp(low, high)

    for _ in range(iterations):
        iteration_targets = targets()
        for _ in range(epochs_per_iteration):
            order = th.randperm(len(x), device=device)
            for start in range(0, len(x), batch_size):
                batch = order[start : start + batch_size]
                predicted = network(x[batch]).gather(1, a[batch, None])[:, 0]
                loss = th.nn.functional.mse_loss(predicted, iteration_targets[batch])
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
    with th.no_grad():
        residual = (targets() - network(x).gather(1, a[:, None])[:, 0]).pow(2).mean().sqrt().item()
    return FQIResult(iterations=iterations, bellman_residual=residual)


def gradient_only_q_network(input_dim: int, n_actions: int, hidden: tuple[int, ...]) -> th.nn.Sequential:
    """``make_q_network`` before 77d1c1c: its output layer starts at PyTorch's random initialisation."""
    layers: list[th.nn.Module] = []
    width = input_dim
    for size in hidden:
        layers += [th.nn.Linear(width, size), th.nn.ReLU()]
        width = size
    layers.append(th.nn.Linear(width, n_actions))
    return th.nn.Sequential(*layers)


class GradientOnlyMlpPolicy(MlpPolicy):
    """``MlpPolicy`` before 77d1c1c: its networks, fitted by ``gradient_only_fit_mlp_fqi``."""

    default_max_iterations = 20  # DEFAULT_MLP_ITERATIONS before 77d1c1c

    def __init__(self, *args: Any, **kwargs: Any):
        state = th.get_rng_state()
        super().__init__(*args, **kwargs)
        # The old networks, drawn from the generator as MlpPolicy drew them, and nothing more drawn from it.
        th.set_rng_state(state)
        self.q_networks = th.nn.ModuleList(
            gradient_only_q_network(self.state_space.shape[0], self.n_actions, self.net_arch)
            for _ in range(self.n_tasks)
        )

    def _fit(
        self, task: int, rows: FitRows, rewards: np.ndarray, gamma: float, max_iterations: int, tol: float
    ) -> FQIResult:
        assert isinstance(rows, TransitionRows)
        inputs, actions, next_inputs, terminated = (tensor.numpy() for tensor in rows.tensors())
        return gradient_only_fit_mlp_fqi(
            inputs,
            actions,
            rewards,
            next_inputs,
            terminated,
            network=self.q_networks[task],
            gamma=gamma,
            iterations=max_iterations,
            learning_rate=self.lr_schedule(1.0),
        )


@dataclass(frozen=True)
class GradientOnlyMlp(Method):
    """The ``MlpPolicy`` method with its refits done as before 77d1c1c (``GradientOnlyMlpPolicy``)."""

    policy: str = "MlpPolicy"

    def make_model(self, env: gym.Env, seed: int) -> TRLSD:
        model = super().make_model(env, seed)
        # As SB3's load builds a model: the policy made again from policy_class, after the same seeding.
        model.policy_class = GradientOnlyMlpPolicy
        model._setup_model()
        return model


def timed_run(method: Method, task: int, seed: int) -> tuple[RunRecord, float]:
    """A transfer run on one torch thread, and the CPU seconds of the process during it."""
    th.set_num_threads(1)
    start = time.process_time()
    record = transfer_run(method, task, seed)
    return record, time.process_time() - start


def mean_and_se(values: np.ndarray) -> str:
    se = values.std(ddof=1) / np.sqrt(len(values)) if len(values) > 1 else float("nan")
    return f"{values.mean():.3f} ± {se:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=24, help="runs of the new MLP and the linear Q")
    parser.add_argument(
        "--gradient-only-runs", type=int, default=24, help="runs of the gradient-only MLP (the first ones)"
    )
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--cache", type=Path, default=None, help="directory keeping finished runs")
    args = parser.parse_args()
    methods = {
        "MLP, gradient-only fit": (GradientOnlyMlp("MLP, gradient-only fit"), args.gradient_only_runs),
        "MLP": (Method("MLP", policy="MlpPolicy"), args.runs),
        "linear": (Method("linear"), args.runs),
    }
    jobs = [((method, run % 25, run), {}) for method, runs in methods.values() for run in range(runs)]
    start = time.perf_counter()
    results = run_jobs(timed_run, jobs, args.workers, description="bench_mlp", cache=args.cache)
    print(
        f"transfer setting: 25,000 source + 1,000 online transitions, run r on task r % 25 with seed r; "
        f"{args.workers} workers, {time.perf_counter() - start:.0f} s in all"
    )
    print("| method | runs | s/run (wall) | CPU s/run | reward, 1,000 steps | reward, last 500 | refits |")
    print("|---|---|---|---|---|---|---|")
    by_method = {}
    for label, (_, runs) in methods.items():
        done, results = results[:runs], results[runs:]
        records = [record for record, _ in done]
        by_method[label] = done
        if not runs:
            continue
        rewards = np.array([record.rewards.mean() for record in records])
        last = np.array([record.rewards[500:].mean() for record in records])
        print(
            f"| {label} | {runs} | {np.mean([record.seconds for record in records]):.1f} "
            f"| {np.mean([cpu for _, cpu in done]):.1f} | {mean_and_se(rewards)} | {mean_and_se(last)} "
            f"| {np.mean([record.policy_updates for record in records]):.0f} |"
        )
    old, new = by_method["MLP, gradient-only fit"], by_method["MLP"]
    common = min(len(old), len(new))
    if not common:
        return
    wall = [np.mean([record.seconds for record, _ in done[:common]]) for done in (old, new)]
    cpu = [np.mean([seconds for _, seconds in done[:common]]) for done in (old, new)]
    print(
        f"\nOn their {common} common runs, the gradient-only MLP takes {wall[0] / wall[1]:.1f}x the wall "
        f"time of the new one per run ({wall[0]:.1f} s against {wall[1]:.1f} s) and {cpu[0] / cpu[1]:.1f}x "
        f"its CPU time ({cpu[0]:.1f} s against {cpu[1]:.1f} s)."
    )
    for name, window in (("1,000 steps", slice(None)), ("last 500", slice(500, None))):
        difference = np.array(
            [
                new_record.rewards[window].mean() - old_record.rewards[window].mean()
                for (old_record, _), (new_record, _) in zip(old[:common], new[:common], strict=True)
            ]
        )
        print(f"Reward over the {name}, new minus gradient-only (paired): {mean_and_se(difference)}")


if __name__ == "__main__":
    main()
