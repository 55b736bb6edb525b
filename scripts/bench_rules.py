"""The rule rows of bench §2 alone: rbx against the minimal loop of the same scene, timed interleaved in one
process (scripts/bench.py's runners, hand loops and ``interleaved``), for the scenes whose rule tree the kernel
specialises: the strip and the plates under the random rule (rough with probability ½; the plates: three rank-1
directions), the plates under the hemisphere rule (also against a hand loop that keeps the whole orientation, as rbx does), the box completely rough.

    .venv/bin/python scripts/bench_rules.py [--seconds 0.3] [--repeats 7] [--rounds 1]

Prints rbx's rate, the hand loop's and their ratio (medians of the repeats) per scene; with ``--rounds`` the
whole set again, so that a change of load between scenes shows.
"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import bench  # noqa: E402

ROWS = (("strip", "random"), ("plates", "random"), ("plates", "hemisphere"), ("box", "rough"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=0.3)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--collisions", type=int, default=0)
    ap.add_argument("--only", default=None)
    args = ap.parse_args()
    for _ in range(args.rounds):
        for scene, rule in ROWS:
            if args.only and args.only not in f"{scene} {rule}":
                continue
            fn = bench.HAND[scene, rule]

            def hand(N, fn=fn):
                t0 = time.perf_counter()
                fn(N)
                return time.perf_counter() - t0, N
            runs = [bench.rbx_run(bench.scene_dict(scene, rule)), hand]
            if (scene, rule) in bench.HAND_KEEPING_A:       # and the hand loop that keeps the whole orientation
                runs.append(lambda N, fn=bench.HAND_KEEPING_A[scene, rule]: hand(N, fn))
            got = bench.interleaved(runs, args)
            rbx_t, hand_t = got[0], got[1]
            also = f"  keeping A {got[2].rate:10.3e}/s  rbx/it {rbx_t.rate / got[2].rate:.2f}" if len(got) > 2 else ""
            print(f"{scene:7s} {rule:10s} rbx {rbx_t.rate:10.3e}/s  hand {hand_t.rate:10.3e}/s  "
                  f"rbx/hand {rbx_t.rate / hand_t.rate:.2f}{also}", flush=True)


if __name__ == "__main__":
    main()
