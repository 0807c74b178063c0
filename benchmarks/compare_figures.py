"""Compare a reproduced figure's JSON (Figure 5 or 8) with a kept one, method by method.

For every method in both files and every aggregate with a standard error (Figure 5: the reward over each
window and the refit count; Figure 8: the last turn's reward and the refit count), prints the two means,
their difference, the kept standard error and whether the difference is within it (and within the standard
error of a difference of two independent means, sqrt(se_new^2 + se_kept^2)). Exits 1 when some aggregate is
outside the kept standard error. Usage::

    python benchmarks/compare_figures.py NEW.json docs/results/protocols/no-restarts/fig5.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterator
from typing import Any


def aggregates(result: dict[str, Any]) -> Iterator[tuple[str, float, float]]:
    """(name, mean, standard error) of every aggregate of one method that has a standard error."""
    for window, value in result.get("reward", {}).items():
        yield f"reward {window}", value["mean"], value["se"]
    for name in ("last_turn_reward", "policy_updates"):
        if isinstance(result.get(name), dict):
            yield name, result[name]["mean"], result[name]["se"]


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("new", help="the reproduced figure's JSON")
    parser.add_argument("kept", help="the kept JSON it is compared with")
    args = parser.parse_args()
    with open(args.new) as new_file, open(args.kept) as kept_file:
        new, kept = json.load(new_file), json.load(kept_file)
    print(f"new: {new['parameters'].get('runs')} runs, protocol {new['parameters']['protocol']['name']}")
    print(f"kept: {kept['parameters'].get('runs')} runs, protocol {kept['parameters']['protocol']['name']}\n")
    print(
        "| method | aggregate | new | kept | difference | kept SE | within it | within the difference's SE |"
    )
    print("|---|---|---|---|---|---|---|---|")
    outside = 0
    for method, result in new["results"].items():
        if method not in kept["results"]:
            continue
        kept_aggregates = {name: (mean, se) for name, mean, se in aggregates(kept["results"][method])}
        for name, mean, se in aggregates(result):
            if name not in kept_aggregates:
                continue
            kept_mean, kept_se = kept_aggregates[name]
            difference = mean - kept_mean
            within = abs(difference) <= kept_se
            outside += not within
            joint = math.hypot(se, kept_se)
            print(
                f"| {method} | {name} | {mean:.4f} | {kept_mean:.4f} | {difference:+.4f} | {kept_se:.4f} "
                f"| {'yes' if within else 'NO'} | {'yes' if abs(difference) <= joint else 'NO'} |"
            )
    print(f"\n{outside} aggregate(s) outside the kept standard error")
    return 1 if outside else 0


if __name__ == "__main__":
    sys.exit(main())
