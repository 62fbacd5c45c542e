"""Helpers shared by several test modules (imported as ``from support import ...``; pytest puts this folder
on ``sys.path``)."""

import contextlib
import io
import signal


class Hang(BaseException):
    """The alarm rang: the command did not return (a BaseException: nothing in the command catches it)."""


@contextlib.contextmanager
def alarm(seconds: float = 60.0):
    """Raise :class:`Hang` in this (main) thread if the block runs past ``seconds``: a hang fails the test."""

    def ring(signum, frame):
        raise Hang(f"no result after {seconds} s")

    previous = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def run_cli(argv: list[str], seconds: float = 60.0) -> tuple[int, str, str]:
    """``softpend.cli.main(argv)`` under :func:`alarm`: its exit status, standard output and standard error."""
    from softpend.cli import main

    out, err = io.StringIO(), io.StringIO()
    with alarm(seconds), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


def refused(argv: list[str], *words: str, codes: tuple[int, ...] = (2,)) -> str:
    """Run ``argv``; assert it exits with one of ``codes`` and one line on stderr, without a traceback, holding
    every word; return that line."""
    rc, _, err = run_cli(argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc in codes and len(lines) == 1 and "Traceback" not in err, (argv, rc, err)
    for word in words:
        assert word in lines[0], (argv, words, lines[0])
    return lines[0]


def one_line_error(capsys, *words: str) -> str:
    """The captured stderr, asserted to be one line without a traceback that contains every word."""
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, err
    return err


#: The front matter of a jupytext MyST notebook, with ``{extra}`` for more front-matter lines.
NOTEBOOK_HEADER = """\
---
jupytext:
  text_representation:
    extension: .md
    format_name: myst
kernelspec:
  display_name: Python 3
  language: python
  name: python3
{extra}---
"""


def gp_predict(gp, x):
    """Posterior mean and variance (M, E) of a :class:`~softpend.pilco.gp.MultiOutputGP`'s latent function at
    deterministic inputs ``x`` (M, D): what the tests sample the moment-matched predictions against."""
    import numpy as np
    import torch

    xt = torch.as_tensor(np.atleast_2d(np.asarray(x, dtype=float)), dtype=torch.float64)
    with torch.no_grad():
        ks = [gp._kernel(xt, gp.inputs, a) for a in range(gp.n_outputs)]
        means = [k @ gp.beta[a] for a, k in enumerate(ks)]
        variances = [torch.exp(gp.log_signal_var[a]) - ((k @ gp.inv_kernel[a]) * k).sum(1) for a, k in enumerate(ks)]
    return torch.stack(means, 1).numpy(), torch.clamp(torch.stack(variances, 1), min=0.0).numpy()
