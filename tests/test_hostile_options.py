"""Hostile input, classes 2 and 7: every numeric option has a range checked at parse time.

Each case gives a command a value outside its option's range (zero, negative, NaN, infinity,
a wrong type); the run must stop while parsing: exit 2, the option named, no traceback, nothing
written. Paths are dummies: nothing may be read before the options are checked.
"""

from __future__ import annotations

import argparse

import pytest
from hostile_world import refused, run

KITTI = ["--dataset", "D", "--centers", "C", "--output", "{out}"]
NUS = ["--dataset", "D", "--version", "v1.0-mini", "--eval-set", "mini_val"]
CLUSTER_K = ["cluster", "semantickitti", *KITTI]
CLUSTER_N = ["cluster", "nuscenes", *NUS, "--centers", "C", "--output", "{out}"]
INFER = ["infer", "--checkpoint", "X.pt", "--data", "D", "--split", "valid", "--out", "{out}"]
SIM_BOXES = ["box-merge", "simulate-boxes", "--dataset", "D", "--output", "{out}"]
SIM_NUS = ["box-merge", "simulate-nuscenes", *NUS, "--output", "{out}/s.json"]
CENTERS = ["centers", "simulate", "--dataset", "D", "--output", "{out}"]
EVAL_K = ["eval", "semantickitti", "--dataset", "D", "--predictions", "P", "--output", "{out}"]
EVAL_4D = ["eval", "semantickitti-4d", "--dataset", "D", "--predictions", "P", "--output", "{out}"]
COMPARE = ["eval", "compare", "A", "B", "--output", "{out}"]
CONFUSIONS = ["eval", "confusions", "A", "--output", "{out}"]
EVAL_N = ["eval", "nuscenes", "--dataroot", "D", "--version", "v1.0-mini", "--result-path", "R",
          "--eval-set", "mini_val", "--output", "{out}"]  # fmt: skip
LABELS = ["nuscenes", "make-labels", "--dataroot", "D", "--version", "v1.0-mini", "--out-dir",
          "{out}"]  # fmt: skip
TRAIN = ["train", "--config", "c.yaml", "--data", "D", "--out", "{out}"]
ABLATE = ["ablate", "--checkpoint", "X.pt", "--data", "D", "--out", "{out}"]
MEANSHIFT = ["--method", "meanshift"]

CASES = [
    # cluster: every method parameter, both datasets
    *[(CLUSTER_K + MEANSHIFT, "--bandwidth", v) for v in ("0", "-1", "nan", "inf", "1e400")],
    (CLUSTER_K + ["--method", "bfs"], "--radius", "0"),
    (CLUSTER_K + ["--method", "dbscan"], "--eps", "-1"),
    (CLUSTER_K + ["--method", "dbscan"], "--min-samples", "0"),
    (CLUSTER_K + ["--method", "hdbscan"], "--min-cluster-size", "1"),
    (CLUSTER_K + ["--method", "hdbscan"], "--cluster-selection-epsilon", "nan"),
    (CLUSTER_K + MEANSHIFT, "--max-iter", "0"),
    (CLUSTER_K + MEANSHIFT, "--min-points", "-5"),
    (CLUSTER_K + MEANSHIFT, "--workers", "0"),
    (CLUSTER_K + MEANSHIFT, "--workers", "-1"),
    (CLUSTER_K + MEANSHIFT, "--min-samples", "2.5"),
    (CLUSTER_N + MEANSHIFT, "--bandwidth", "-inf"),
    (CLUSTER_N + ["--method", "hdbscan"], "--min-cluster-size", "0"),
    # infer
    (INFER, "--max-scans", "-1"),
    (INFER, "--bandwidth", "nan"),
    (INFER, "--threads", "-1"),
    (INFER, "--threads", "0"),
    (INFER, "--device", "banana"),
    (INFER, "--tta-views", "0"),
    (INFER, "--tta-views", "17"),
    (INFER, "--bn-stats", "batch"),
    (INFER, "--orphans", "unlabeled"),
    # box-merge simulators
    (SIM_BOXES, "--miss-rate", "2"),
    (SIM_BOXES, "--position-sigma", "nan"),
    (SIM_BOXES, "--fp-rate", "inf"),
    (SIM_BOXES, "--seed", "-1"),
    (SIM_NUS, "--miss-rate", "-0.1"),
    (SIM_NUS, "--seed", "-5"),
    (SIM_NUS, "--yaw-sigma", "nan"),
    # centers simulate
    (CENTERS, "--seed", "-1"),
    (CENTERS, "--workers", "0"),
    (CENTERS, "--outlier-rate", "2"),
    (CENTERS, "--base-sigma", "nan"),
    (CENTERS, "--range-gain", "-1"),
    # evaluation
    (EVAL_K, "--workers", "0"),
    (EVAL_K, "--min-inst-points", "-1"),
    *[(EVAL_K, "--by-range", v) for v in ("0,nan", "0,inf", "10,5", "5", "0,a")],
    (EVAL_K, "--bootstrap", "-1"),
    (EVAL_K, "--bootstrap", "1.5"),
    (COMPARE, "--bootstrap", "0"),
    (COMPARE, "--level", "1"),
    (COMPARE, "--level", "nan"),
    (COMPARE, "--seed", "-1"),
    (CONFUSIONS, "--top", "0"),
    (CONFUSIONS, "--top", "x"),
    (EVAL_4D, "--workers", "-2"),
    (EVAL_4D, "--by-range", "nan,1"),
    (EVAL_N, "--workers", "0"),
    (EVAL_N, "--min-inst-points", "-1"),
    (EVAL_N, "--by-range", "0,10,inf"),
    (LABELS, "--workers", "0"),
    # DS-Net commands
    (TRAIN, "--epochs", "-1"),
    (TRAIN, "--seed", "-1"),
    (TRAIN, "--seed", "1.5"),
    (TRAIN, "--threads", "-1"),
    (TRAIN, "--device", "banana"),
    (TRAIN, "--train-sequences", "00,00"),
    (TRAIN, "--val-sequences", "x"),
    (ABLATE, "--steps", "-1"),
    (ABLATE, "--lr", "0"),
    (ABLATE, "--lr", "nan"),
    (ABLATE, "--seed", "-1"),
    (ABLATE, "--threads", "0"),
    (ABLATE, "--max-val-scans", "-2"),
    (ABLATE, "--train-sequences", "08,08"),
    (["demo", "--out", "{out}"], "--workers", "0"),
    (["synth", "semantickitti", "--out", "{out}"], "--seed", "-1"),
    (["synth", "nuscenes", "--out", "{out}"], "--scenes", "0"),
    (["synth", "nuscenes", "--out", "{out}"], "--samples", "-3"),
]


@pytest.mark.parametrize(("argv", "option", "value"), CASES, ids=lambda x: str(x)[:40])
def test_out_of_range_option_stops_at_parse_time(argv, option, value, tmp_path, capsys):
    out = tmp_path / "out"
    full = [a.replace("{out}", str(out)) for a in argv] + [option, value]
    err = refused(full, capsys, names=[option], watch=[tmp_path])
    assert "usage:" in err  # argparse's own message: raised before any handler ran


@pytest.mark.parametrize(
    "argv",
    [
        EVAL_K + ["--sequences", "08,08"],
        EVAL_K + ["--sequences", "08", "8"],  # the same sequence, spelled twice
        EVAL_4D + ["--sequences", "08,8"],
        [
            "validate",
            "semantickitti",
            "--dataset",
            "D",
            "--predictions",
            "P",
            "--sequences",
            "08,08",
        ],  # fmt: skip
        CLUSTER_K + MEANSHIFT + ["--sequences", "08", "08"],
        CENTERS + ["--sequences", "00,00"],
        SIM_BOXES + ["--sequences", "08", "8"],
        INFER[:-2] + ["--sequences", "07,07", "--out", "{out}"],
        EVAL_K + ["--sequences", "²"],  # isdigit() but not a number
        EVAL_K + ["--sequences", ","],
    ],
    ids=lambda a: " ".join(a[:2] + a[-2:]),
)
def test_repeated_or_bad_sequences_refused(argv, tmp_path, capsys):
    full = [a.replace("{out}", str(tmp_path / "out")) for a in argv]
    refused(full, capsys, names=["--sequences"], watch=[tmp_path])


def test_old_infer_split_spelling_checks_sequences_too(tmp_path, capsys):
    """``infer --split 07,07`` (the old spelling of --sequences) is refused like --sequences."""
    argv = [a.replace("{out}", str(tmp_path / "out")) for a in INFER]
    argv[argv.index("valid")] = "07,07"
    refused(argv, capsys, names=["--split", "07 given twice"], watch=[tmp_path])


def test_cuda_device_that_does_not_exist(tmp_path, capsys):
    import torch

    n = torch.cuda.device_count() if torch.cuda.is_available() else 0
    device = f"cuda:{n}" if n else "cuda"
    for argv in (INFER, TRAIN):
        full = [a.replace("{out}", str(tmp_path / "out")) for a in argv] + ["--device", device]
        refused(full, capsys, names=["--device", device], watch=[tmp_path])


def test_one_vocabulary_for_scan_selection(capsys):
    """Every scan-selecting command takes --split and --sequences (in both spellings)."""
    from panoptic_bench.cli import build_parser

    parser = build_parser()
    commands = [
        ["eval", "semantickitti"], ["eval", "semantickitti-4d"], ["validate", "semantickitti"],
        ["cluster", "semantickitti"], ["centers", "simulate"], ["box-merge", "semantickitti"],
        ["box-merge", "simulate-boxes"], ["infer"],
    ]  # fmt: skip
    for words in commands:
        sub = parser
        for w in words:
            sub = next(a for a in sub._actions if a.dest and a.choices and w in a.choices)
            sub = sub.choices[w]
        options = {s for a in sub._actions for s in a.option_strings}
        assert {"--split", "--sequences"} <= options, words
        action = sub._option_string_actions["--sequences"]
        assert action.nargs == "+", words
        ns = argparse.Namespace()
        action(sub, ns, ["8,09", "10"], "--sequences")
        assert ns.sequences == ["08", "09", "10"], words
    status, _, _ = run(["eval", "semantickitti", "--help"], capsys)
    assert status == 0


def test_synth_sequence_given_twice(tmp_path, capsys):
    """``synth --sequences 08:1,8:2`` names sequence 08 twice: refused before anything is written."""
    argv = ["synth", "semantickitti", "--out", tmp_path / "out", "--sequences", "08:1,8:2"]
    refused(argv, capsys, names=["08 given twice"], watch=[tmp_path])
