"""The ``ineid study`` commands' engines: experiments that measure ineid and check the paper's claims.

:mod:`.noise` (identification error against sensor noise), :mod:`.formulations` (the base wrench
against joint torques on MuJoCo recordings), :mod:`.sensors` (which sensors buy what, rehearsed),
:mod:`.paper` (the paper's section 4: lsqlin, lsqnonlin, linear on its dataset), and the paper's
network exploration re-run (:mod:`.paper_networks`) with its claims judged (:mod:`.paper_claims`);
:mod:`.mujoco_sim` simulates the arm in MuJoCo with joint friction (an independent engine: the
formulations study's data and the tests' recordings).
Each writes rows (CSV) and a plot; none is needed by the main job.
"""
