"""``softpend fit-model``: train a learned dynamics model on a babbling dataset and report its accuracy."""

from __future__ import annotations

import argparse

from softpend.commands.options import FieldOption, Option, add_command, field_options, field_values

#: ``(flag, TrainConfig field, type, help, allowed range)`` of the training options (the ranges bound the work).
_OPTIONS: tuple[FieldOption, ...] = (
    ("--history", "history", int, "past position frames in the state", (0, 1000)),
    ("--activation", "activation", str, "hidden activation", None),
    ("--ensemble-size", "ensemble_size", int, "ensemble members", (1, 1000)),
    ("--max-epochs", "max_epochs", int, "epoch limit", (1, 100_000)),
    ("--batch-size", "batch_size", int, "minibatch size", (1, 10**8)),
    ("--learning-rate", "learning_rate", float, "Adam step size", (1e-12, 1e30)),  # Adam's step stays a float32
    ("--patience", "patience", int, "early-stopping patience [epochs]", (1, 100_000)),
    ("--validation-fraction", "validation_fraction", float, "fraction of trials for validation", None),
    ("--seed", "seed", int, "seed", None),
)


def _integers(text: str) -> tuple[int, ...]:
    return tuple(int(w) for w in text.split(",") if w.strip())


DESCRIPTION = """Fit the one-step dynamics network to a babbling dataset, save OUTPUT.pt + OUTPUT.json (metadata,
metrics) and print one-step and rollout errors on the validation trials (and --test-data) as JSON."""


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.sysid import TrainConfig

    d = TrainConfig()
    widths = dict(type=_integers, default=",".join(map(str, d.hidden_widths)), help="comma-separated (16,16,16)")
    options: list[Option] = [
        ("dataset", None, dict(help="training dataset (.npz)")),
        ("output", None, dict(help="model path stem: writes OUTPUT.pt and OUTPUT.json")),
        ("--information", None, dict(choices=("full", "limited"), default=d.information, help=f"({d.information})")),
        ("--velocity-source", None, dict(choices=("observed", "true"), default=d.velocity_source, help="(observed)")),
        ("--hidden-widths", None, widths),
        *field_options(d, _OPTIONS),
        ("--threads", (1, 1024), dict(type=int, default=1, help="torch threads (default 1)")),
        ("--test-data", None, dict(default=None, help="held-out dataset (.npz) to evaluate on as well")),
        ("--no-progress", None, dict(action="store_true", help="hide progress bars")),
    ]
    help = "train a learned dynamics model (softpend.sysid) on a dataset and report its accuracy"
    add_command(subparsers, "fit-model", help, options, run, description=DESCRIPTION)


def run(args: argparse.Namespace) -> int:
    import torch

    from softpend.io.outputs import Outputs, finite_or_none, json_text, output_name
    from softpend.sysid import TrainConfig, fit_dynamics_model, load_dataset, save_model
    from softpend.sysid.metrics import evaluate_model
    from softpend.sysid.model import model_paths

    output_name(args.output, ".json" if args.output.endswith(".json") else ".pt", "model path")  # a file's name
    outputs = Outputs()
    model_files = [outputs.file(path, what="model file") for path in model_paths(args.output)]
    chosen = {key: getattr(args, key) for key in ("information", "velocity_source", "hidden_widths")}
    config = TrainConfig(**chosen, **field_values(args, _OPTIONS))
    dataset = load_dataset(args.dataset)
    test = load_dataset(args.test_data, expected_dt_s=dataset.dt_s) if args.test_data else None
    torch.set_num_threads(args.threads)
    result = fit_dynamics_model(dataset, config, progress=not args.no_progress)
    metrics = {"validation": evaluate_model(result.model, dataset, result.val_trials)}
    if test is not None:
        metrics["test"] = evaluate_model(result.model, test)
    metadata = dict(result.metadata(), metrics=metrics, dataset=str(args.dataset), test_dataset=args.test_data)
    weights, meta = save_model(args.output, result.model, finite_or_none(metadata))
    for path in model_files:  # written atomically by the model's writer
        outputs.done(path)
    summary = {"weights": str(weights), "metadata": str(meta), "train_time_s": round(result.train_time_s, 2)}
    print(json_text(dict(summary, metrics=metrics), indent=2))
    return 0
