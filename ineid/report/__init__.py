"""What a solve is worth, shown: the validation plot and the HTML report a lab can send on.

Data flow: a results file (:mod:`ineid.identify.results`) and its datasets -> the validation
(:mod:`.plot`: measured against predicted over time) and the residual tests (:mod:`.residuals`)
-> figures (:mod:`.figures`) and sections (:mod:`.sections`) -> one self-contained page
(:mod:`.html`, the Jinja2 template ``templates/report.html.j2``).
"""

from __future__ import annotations

from ineid.report.html import ReportInputs, build_report, inputs_from_files, write_report
from ineid.report.plot import Validation, plot_validation, validation, validation_on

__all__ = [
    "ReportInputs",
    "Validation",
    "build_report",
    "inputs_from_files",
    "plot_validation",
    "validation",
    "validation_on",
    "write_report",
]
