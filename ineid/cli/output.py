"""Console output of the ``ineid`` commands: rich tables and progress bars.

Results go to stdout; progress bars and messages go to stderr, so ``ineid ... > file``
keeps the tables. Nothing here computes: each function renders what the library returned.
"""

from __future__ import annotations

import shutil


def console():
    """A stdout console wide enough for ineid's tables."""
    from rich.console import Console  # noqa: PLC0415

    return Console(highlight=False, soft_wrap=False, width=max(150, shutil.get_terminal_size((120, 24)).columns))


def console_err():
    from rich.console import Console  # noqa: PLC0415

    return Console(stderr=True, highlight=False)


def table(title: str, columns, left=()):
    """A rich table with a left-justified title; columns right-justified unless named in ``left``."""
    from rich.table import Table  # noqa: PLC0415

    t = Table(title=title, title_justify="left")
    for col in columns:
        t.add_column(col, justify="left" if col in left else "right")
    return t


class ProgressBar:
    """A rich progress bar driven by ``callback(done, total)``; silent with ``-q``."""

    def __init__(self, description: str, unit: str, quiet: bool) -> None:
        from rich.progress import (  # noqa: PLC0415
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(unit),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            disable=quiet,
            console=console_err(),
        )
        self._task = None
        self._description = description

    def __enter__(self):
        self._progress.__enter__()
        return self

    def __exit__(self, *exc):
        return self._progress.__exit__(*exc)

    def set_description(self, text: str) -> None:
        if self._task is not None:
            self._progress.update(self._task, description=text)

    def __call__(self, done: int, total: int) -> None:
        if self._task is None:
            self._task = self._progress.add_task(self._description, total=total)
        self._progress.update(self._task, completed=done, total=total)


def print_results(res, out) -> None:
    """The summary of ``ineid solve``: successes, held-out error, error tables or the estimates."""
    import numpy as np  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    from ineid.identify import error_summary  # noqa: PLC0415

    con = console()
    n_ok = int(res.success.sum())
    total = res.meta.get("total_seconds", float("nan"))
    con.print(
        f"[bold]{res.settings.method}[/bold] on {res.meta['robot']}: {n_ok}/{res.n} configurations identified "
        f"in {total:.2f} s ({1e3 * total / max(res.n, 1):.2f} ms each); fitted {res.n_frames_fit} frames each"
        + (f", validated on {res.n_frames_validation}" if res.n_frames_validation else "")
    )
    if n_ok < res.n:
        statuses, counts = np.unique(res.status[~res.success].astype(str), return_counts=True)
        con.print("failed: " + "; ".join(f"{c} x {s}" for s, c in zip(statuses, counts)))
    if res.n_frames_validation and n_ok:
        rel = res.validation_rel[res.success]
        with np.errstate(invalid="ignore"):  # inf (a zero wrench) between two values: nan (solve warns)
            median, p95 = np.median(rel), np.percentile(rel, 95)
        con.print(f"held-out wrench error ||w - Psi theta_hat|| / ||w||: median {median:.3g}, "
                  f"95th percentile {p95:.3g}")
    if res.theta_true is not None and n_ok:
        for title, est, truth, names, ident in (
            ("standard parameters", res.theta_hat, res.theta_true, res.param_names, res.base.identifiable),
            ("base parameters (what the data determine)", res.base_hat, res.base_true, res.base.names, None),
        ):
            table = Table(title=f"Relative error, {title}, over {n_ok} configurations", title_justify="left")
            for col in ("parameter", "median", "95th pct", "within 1%", "within 5%") + (("identifiable",) if ident is not None else ()):
                table.add_column(col, justify="left" if col in ("parameter", "identifiable") else "right")
            for row in error_summary(est, truth, names, res.success, ident):
                cells = [row.name, f"{row.median:.3g}", f"{row.p95:.3g}", f"{100 * row.within_1:.1f}%",
                         f"{100 * row.within_5:.1f}%"]
                if ident is not None:
                    cells.append("yes" if row.identifiable else "no (prior)")
                table.add_row(*cells)
            con.print(table)
        from ineid.params import all_links_physical  # noqa: PLC0415

        valid = all_links_physical(np.nan_to_num(res.theta_hat[res.success]))
        con.print(f"physically valid estimates: {100 * valid.mean():.1f}%")
    elif n_ok:
        i = int(np.flatnonzero(res.success)[0])
        table = Table(title=f"Estimates of configuration {int(res.config_index[i])} (SI, about each link origin)",
                      title_justify="left")
        for col in ("parameter", "estimate", "std", "prior (CAD)", "identifiable"):
            table.add_column(col, justify="left" if col in ("parameter", "identifiable") else "right")
        for k, name in enumerate(res.param_names):
            std = res.theta_std[i, k]
            table.add_row(name, f"{res.theta_hat[i, k]:.6g}", "-" if not np.isfinite(std) else f"{std:.3g}",
                          f"{res.theta_prior[k]:.6g}", "yes" if res.base.identifiable[k] else "no (prior)")
        con.print(table)
        table = Table(title="Base parameters", title_justify="left")
        for col in ("base parameter", "estimate", "std"):
            table.add_column(col, justify="left" if col == "base parameter" else "right")
        for k, name in enumerate(res.base.names):
            table.add_row(name, f"{res.base_hat[i, k]:.6g}", f"{res.base_std[i, k]:.3g}")
        con.print(table)
    if res.bias_hat is not None and n_ok:
        i = int(np.flatnonzero(res.success)[0])
        con.print(f"sensor offsets of configuration {int(res.config_index[i])} (N, N*m, the wrench's frame): "
                  + ", ".join(f"{a} {b:.5g} +- {s:.2g}" for a, b, s in
                              zip(("fx", "fy", "fz", "mx", "my", "mz"), res.bias_hat[i], res.bias_std[i], strict=True)))
    con.print(f"wrote {out}")


def print_evaluation(ev) -> None:
    """The report of ``ineid evaluate``: the network beside the floor and least squares."""
    from rich.table import Table  # noqa: PLC0415

    con = console()
    con.print(f"evaluated on {ev.n_configs} configurations ({ev.extra.get('configs')}), {ev.frames_used} frames each")
    table = Table(title="Relative error of the standard parameters (median / 95th percentile) and R^2", title_justify="left")
    for col in ("parameter", "network", "p95", "R^2", "floor (null space)", "linear LS", "Gaussian prior",
                "identifiable"):
        table.add_column(col, justify="left" if col in ("parameter", "identifiable") else "right")
    for k, name in enumerate(ev.network["names"]):
        lin = f"{ev.linear['median'][k]:.3g}" if ev.linear else "-"
        gp = f"{ev.gaussian['median'][k]:.3g}" if ev.gaussian else "-"
        table.add_row(name, f"{ev.network['median'][k]:.3g}", f"{ev.network['p95'][k]:.3g}",
                      f"{ev.network['r2'][k]:.3f}", f"{ev.floor['median'][k]:.3g}", lin, gp,
                      "yes" if ev.identifiable[k] else "no")
    con.print(table)
    table = Table(title="Relative error of the base parameters (median)", title_justify="left")
    for col in ("base parameter", "network", "R^2", "linear LS", "Gaussian prior"):
        table.add_column(col, justify="left" if col == "base parameter" else "right")
    for k, name in enumerate(ev.network_base["names"]):
        lin = f"{ev.linear_base['median'][k]:.3g}" if ev.linear_base else "-"
        gp = f"{ev.gaussian_base['median'][k]:.3g}" if ev.gaussian_base else "-"
        table.add_row(name, f"{ev.network_base['median'][k]:.3g}", f"{ev.network_base['r2'][k]:.3f}", lin, gp)
    con.print(table)
    lin = (f"; linear LS: standard {ev.linear['overall_median']:.4g}, base {ev.linear_base['overall_median']:.4g}, "
           f"physical {100 * ev.linear_physical_share:.0f}%") if ev.linear else ""
    if ev.gaussian:
        lin += f"; Gaussian prior: standard {ev.gaussian['overall_median']:.4g}, base {ev.gaussian_base['overall_median']:.4g}"
    con.print(
        f"median over all parameters: network standard {ev.network['overall_median']:.4g}, base "
        f"{ev.network_base['overall_median']:.4g} (per sample, before averaging: {ev.per_sample_median:.4g}); "
        f"null-space floor {ev.floor['overall_median']:.4g}{lin}"
    )
    rms = ", ".join(f"{v:.3g}" for v in ev.wrench_rms)
    con.print(f"wrench residual of the predictions, RMS per axis (N, N*m): {rms}; normalized {ev.wrench_normalized:.4g}; "
              f"physically valid predictions {100 * ev.physical_share:.0f}%")


def print_findings(findings) -> None:
    """Plausibility warnings (:class:`ineid.data.plausibility.Finding`), one line each on stderr.

    Shown with ``-q`` too: a quiet run is the one whose user would not look at the numbers.
    """
    import click  # noqa: PLC0415

    for f in findings:
        click.echo(f"ineid: warning: {f.message}", err=True)
