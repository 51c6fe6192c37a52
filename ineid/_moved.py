"""Modules that moved: their old import paths still work for one release, with a deprecation warning.

``import ineid.identify.excite`` (and ``from ineid.identify.excite import design_excitation``) gives the
module's new home, :mod:`ineid.excite.design`, after a :class:`DeprecationWarning` naming it: a finder on
``sys.meta_path`` (installed when ``ineid`` is imported) answers for the old names in :data:`MOVED` and
hands out the new module itself, so both names are one module object. Nothing in the package imports an
old name (``tests/test_architecture.py`` checks); the table goes in ineid {REMOVED_IN}.

Imports only the standard library.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings

REMOVED_IN = "0.3"
"""The release without the old names."""

MOVED: dict[str, str] = {
    "ineid.identify.excite": "ineid.excite.design",
    "ineid.identify.excite_collision": "ineid.excite.collision",
    "ineid.identify.excite_criterion": "ineid.excite.criterion",
    "ineid.identify.excite_safety": "ineid.excite.safety",
    "ineid.identify.excite_states": "ineid.excite.states",
    "ineid.identify.excite_trajectory": "ineid.excite.trajectory",
    "ineid.identify.html_report": "ineid.report.html",
    "ineid.identify.report": "ineid.report.plot",
    "ineid.identify.report_figures": "ineid.report.figures",
    "ineid.identify.report_sections": "ineid.report.sections",
    "ineid.identify.residuals": "ineid.report.residuals",
    "ineid.identify.study": "ineid.studies.noise",
    "ineid.identify.study_formulations": "ineid.studies.formulations",
    "ineid.identify.study_paper": "ineid.studies.paper",
    "ineid.identify.study_sensors": "ineid.studies.sensors",
    "ineid.learn.paper_networks": "ineid.studies.paper_networks",
    "ineid.learn.paper_claims": "ineid.studies.paper_claims",
    "ineid.identify.export": "ineid.robots.urdf_write",
    "ineid.identify.export_mjcf": "ineid.robots.mjcf_write",
    "ineid.robots.chain": "ineid.chain",
    "ineid.data.meta": "ineid.data.dataset.meta",
    "ineid.data.schema": "ineid.data.dataset.schema",
    "ineid.data.read": "ineid.data.dataset.read",
    "ineid.data.write": "ineid.data.dataset.write",
    "ineid.data.hdf5_audit": "ineid.data.dataset.hdf5_audit",
    "ineid.data.state_estimation": "ineid.data.imu.estimation",
    "ineid.data.gyro_bias": "ineid.data.imu.gyro_bias",
    "ineid.data.prior_weights": "ineid.data.imu.prior_weights",
    "ineid.data.streams": "ineid.data.recordings.streams",
    "ineid.data.csv_import": "ineid.data.recordings.csv_import",
    "ineid.data.csv_rows": "ineid.data.recordings.csv_rows",
    "ineid.data.bags": "ineid.data.recordings.bags",
    "ineid.data.bag_metadata": "ineid.data.recordings.bag_metadata",
    "ineid.data.signals": "ineid.data.recordings.signals",
    "ineid.data.recording": "ineid.data.recordings.pipeline",
    "ineid.data.recording_limits": "ineid.data.recordings.limits",
    "ineid.data.recording_channels": "ineid.data.recordings.channels",
    "ineid.data.recording_imu": "ineid.data.recordings.imus",
    "ineid.data.import_summary": "ineid.data.recordings.summary",
    "ineid.data.plausibility": "ineid.data.recordings.plausibility",
    "ineid.data.sampling": "ineid.data.synthesis.sampling",
    "ineid.data.noise": "ineid.data.synthesis.noise",
    "ineid.data.generate": "ineid.data.synthesis.generate",
    "ineid.data.trajectory": "ineid.data.synthesis.trajectory",
    "ineid.data.imu_rehearsal": "ineid.data.synthesis.imu_rehearsal",
    "ineid.data.mujoco_sim": "ineid.studies.mujoco_sim",
    "ineid.identify.weighting": "ineid.identify.least_squares",
}
"""Old module path -> new module path."""


class _Alias(importlib.abc.Loader):
    """Loads an old name as the new module (the same object), warning once per import."""

    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec):
        warnings.warn(
            f"{spec.name} moved to {self.new}; import it from there (the old name goes in ineid {REMOVED_IN})",
            DeprecationWarning,
            stacklevel=2,
        )
        return importlib.import_module(self.new)

    def exec_module(self, module) -> None:
        """The new module is already executed."""


class MovedFinder(importlib.abc.MetaPathFinder):
    """Finds the old names of :data:`MOVED`; any other name is left to the other finders."""

    def find_spec(self, fullname, path=None, target=None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _Alias(new))


def install() -> None:
    """Put :class:`MovedFinder` on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, MovedFinder())
