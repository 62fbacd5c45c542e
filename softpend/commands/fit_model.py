"""``softpend fit-model``: train a learned dynamics model on a babbling dataset and report its accuracy."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.sysid import TrainConfig

    d = TrainConfig()
    parser = subparsers.add_parser(
        "fit-model",
        help="train a learned dynamics model (softpend.sysid) on a dataset and report its accuracy",
        description="Fit the one-step dynamics network to a dataset written by `softpend babble` (or a rig), save it "
        "as OUTPUT.pt (state dict) + OUTPUT.json (metadata with metrics), and print one-step and open-loop "
        "rollout errors on the validation trials (and on --test-data if given) as JSON.",
    )
    parser.add_argument("dataset", help="training dataset (.npz)")
    parser.add_argument("output", help="model path stem: writes OUTPUT.pt and OUTPUT.json")
    parser.add_argument(
        "--information", choices=("full", "limited"), default=d.information, help=f"information level ({d.information})"
    )
    parser.add_argument(
        "--history", type=int, default=d.history, help=f"past position frames in the state ({d.history})"
    )
    parser.add_argument(
        "--velocity-source",
        choices=("observed", "true"),
        default=d.velocity_source,
        help=f"velocities ({d.velocity_source})",
    )
    parser.add_argument(
        "--hidden-widths", default=",".join(map(str, d.hidden_widths)), help="comma-separated hidden widths (16,16,16)"
    )
    parser.add_argument("--activation", default=d.activation, help=f"hidden activation ({d.activation})")
    parser.add_argument(
        "--ensemble-size", type=int, default=d.ensemble_size, help=f"ensemble members ({d.ensemble_size})"
    )
    parser.add_argument("--max-epochs", type=int, default=d.max_epochs, help=f"epoch limit ({d.max_epochs})")
    parser.add_argument("--batch-size", type=int, default=d.batch_size, help=f"minibatch size ({d.batch_size})")
    parser.add_argument(
        "--learning-rate", type=float, default=d.learning_rate, help=f"Adam step size ({d.learning_rate})"
    )
    parser.add_argument(
        "--patience", type=int, default=d.patience, help=f"early-stopping patience [epochs] ({d.patience})"
    )
    parser.add_argument(
        "--validation-fraction", type=float, default=d.validation_fraction, help="fraction of trials for validation"
    )
    parser.add_argument("--seed", type=int, default=d.seed, help=f"seed ({d.seed})")
    parser.add_argument("--test-data", default=None, help="held-out dataset (.npz) to evaluate on as well")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from softpend.commands.options import check_numbers
    from softpend.io.outputs import Outputs, finite_or_none, json_text, output_name
    from softpend.sysid import TrainConfig, fit_dynamics_model, load_dataset, save_model
    from softpend.sysid.metrics import evaluate_model
    from softpend.sysid.model import model_paths
    from softpend.sysid.training import parse_widths

    # before anything starts: the epoch loop and the ensemble are bounded (work-size estimates bound the memory)
    check_numbers(
        args,
        {
            "--threads": (1, 1024),
            "--max-epochs": (1, 100_000),
            "--patience": (1, 100_000),
            "--ensemble-size": (1, 1000),
            "--history": (0, 1000),
            "--batch-size": (1, 10**8),
            "--learning-rate": (1e-12, 1e30),
        },
    )  # Adam's step stays a float32
    output_name(args.output, ".json" if args.output.endswith(".json") else ".pt", "model path")  # a file's name
    outputs = Outputs()
    # before the work: a model this command wrote may be replaced, nothing else
    model_files = [outputs.file(path, what="model file") for path in model_paths(args.output)]
    config = TrainConfig(
        information=args.information,
        history=args.history,
        velocity_source=args.velocity_source,
        hidden_widths=parse_widths(args.hidden_widths),
        activation=args.activation,
        ensemble_size=args.ensemble_size,
        max_epochs=args.max_epochs,
        batch_size=args.batch_size,
        learning_rate=args.learning_rate,
        patience=args.patience,
        validation_fraction=args.validation_fraction,
        seed=args.seed,
    )
    dataset = load_dataset(args.dataset)
    # a model predicts one step of the training data's dt_s: held-out data at another step is not a test of it
    test = load_dataset(args.test_data, expected_dt_s=dataset.dt_s) if args.test_data else None
    torch.set_num_threads(args.threads)
    result = fit_dynamics_model(dataset, config, progress=not args.no_progress)
    metrics = {"validation": evaluate_model(result.model, dataset, result.val_trials)}
    if test is not None:
        metrics["test"] = evaluate_model(result.model, test)
    metadata = finite_or_none(
        dict(result.metadata(), metrics=metrics, dataset=str(args.dataset), test_dataset=args.test_data)
    )
    weights, meta = save_model(args.output, result.model, metadata)
    for path in model_files:  # written atomically by the model's writer
        outputs.done(path)
    print(
        json_text(
            {
                "weights": str(weights),
                "metadata": str(meta),
                "train_time_s": round(result.train_time_s, 2),
                "metrics": metrics,
            },
            indent=2,
        )
    )
    return 0
