#!/usr/bin/env python3
"""kinetree against the Python baseline on the scale scenario, in one sitting.

    python compare.py [--points 1000] [--frames 1000] [--runs 3] [--kinetree PATH]

Writes the scale scenario (`kinetree simulate --mechanism scale`, 15 % dropout, seed 0) to a
temporary folder, then times `kinetree discover` and `paper_baseline.py` on it in turn, each
`--runs` times, as whole processes (reading the tracks and starting up included), both with
the noise level given. Prints each run, the medians and their ratio.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def simulate_scale(kinetree, folder, points, frames, seed=0):
    """Writes the scale scenario of `points` keypoints over `frames` frames into `folder`."""
    subprocess.run(
        [kinetree, "simulate", "--mechanism", "scale", "--points", str(points), "--frames",
         str(frames), "--dropout", "0.15", "--seed", str(seed), "-o", str(folder), "-q"],
        check=True,
        stdout=subprocess.DEVNULL,
    )


def timed(command):
    """Wall-clock seconds of `command`, which must succeed."""
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=1000)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--kinetree",
        default=os.environ.get("KINETREE_BIN", "kinetree"),
        help="the kinetree binary (default: $KINETREE_BIN, else kinetree on the PATH)",
    )
    args = parser.parse_args(argv)
    if args.runs < 1:
        sys.exit("--runs must be at least 1")
    with tempfile.TemporaryDirectory() as folder:
        data = os.path.join(folder, "data")
        simulate_scale(args.kinetree, data, args.points, args.frames)
        tracks = os.path.join(data, "tracks.npy")
        ours = [args.kinetree, "discover", tracks, "--noise-sigma", "0.001", "--no-poses",
                "-q", "-o", os.path.join(folder, "model.json")]
        theirs = [sys.executable, os.path.join(HERE, "paper_baseline.py"), tracks,
                  "--noise-sigma", "0.001"]
        times = {"kinetree": [], "baseline": []}
        for run in range(args.runs):
            times["kinetree"].append(timed(ours))
            times["baseline"].append(timed(theirs))
            print(f"run {run + 1}: kinetree {times['kinetree'][-1]:.2f} s, "
                  f"baseline {times['baseline'][-1]:.2f} s")
    k, b = (statistics.median(times[name]) for name in ("kinetree", "baseline"))
    print(f"N = {args.points}, T = {args.frames}: median kinetree {k:.2f} s, "
          f"baseline {b:.2f} s, baseline / kinetree = {b / k:.1f}")


if __name__ == "__main__":
    main()
