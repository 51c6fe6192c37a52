"""The summary ``ineid excite`` prints: the design against the best random candidate, how each start ended, the
bounds in force and the feasibility check (nothing here computes: it renders the :class:`ExcitationResult`)."""

from __future__ import annotations

from ineid.cli.output import console, shown, table


def print_design(res, model) -> None:
    """The summary: criterion, scaled condition number and expected std, designed beside random Fourier."""
    import numpy as np

    from ineid.robots.gravity import describe_gravity

    con = console()
    opt, rnd = res.optimized, res.random
    sigma = res.sigma
    con.print(
        f"[bold]{res.criterion}[/bold] design of {shown(res.settings['robot'])} "
        f"({shown(', '.join(res.settings['unknown_links']))} "
        f"unknown{'; sensor offsets estimated' if res.base.bias else ''}): {res.base.rank} base parameters, "
        f"{len(res.starts)} starts from the best of {res.n_candidates} random feasible trajectories in "
        f"{res.seconds:.1f} s"
    )
    con.print(describe_gravity(model.gravity))
    channels = res.base.channels
    if len(channels) == 1 and channels.keys == ("wrench",):
        noise = (
            f"white Gaussian wrench noise, std {sigma[0]:g} {sigma[1]:g} {sigma[2]:g} N, "
            f"{sigma[3]:g} {sigma[4]:g} {sigma[5]:g} N*m"
        )
    else:
        parts, start = [], 0
        for c in channels:
            n_a, units = c.n_axes(model), c.units(model)
            values = sigma[start : start + n_a]
            start += n_a
            same = np.all(values == values[0]) and len(set(units)) == 1
            stds = (
                f"{values[0]:g} {units[0]}"
                if same
                else " ".join(f"{v:g} {u}" for v, u in zip(values, units, strict=True))
            )
            parts.append(f"{shown(c.describe())}: std {stds}")
        noise = "white Gaussian noise; " + "; ".join(parts)
        if channels.n_extra(model):
            noise += f"; extra parameters {shown(', '.join(channels.extra_names(model)))} designed for too"
    states = (
        "joint states exact"
        if res.states is None
        else f"joint states from {shown(res.states['described'])}: their errors add to the noise (below)"
    )
    con.print(f"noise model: {noise} per sample, {opt.n_samples} samples at {res.rate:g} Hz; {states}")
    best = res.best_random
    t = table(
        f"Design vs the best of {res.n_candidates} random feasible trajectories (same period, harmonics and bounds; "
        "the median one: a typical random Fourier trajectory)",
        ("", "designed", "best random", "ratio", "median random Fourier"),
        left=("",),
    )
    t.add_row(
        "-log det M (d-opt)",
        f"{opt.d_opt:.4g}",
        f"{best.d_opt:.4g}",
        f"{best.d_opt - opt.d_opt:+.3g} (diff)",
        f"{rnd.d_opt:.4g}",
    )
    t.add_row(
        "scaled condition number",
        f"{opt.condition_number:.4g}",
        f"{best.condition_number:.4g}",
        f"{best.condition_number / opt.condition_number:.3g}x",
        f"{rnd.condition_number:.4g}",
    )
    t.add_row(
        "median expected relative std",
        f"{np.median(opt.rel_std):.3g}",
        f"{np.median(best.rel_std):.3g}",
        f"{np.median(best.rel_std) / np.median(opt.rel_std):.3g}x",
        f"{np.median(rnd.rel_std):.3g}",
    )
    con.print(t)
    print_answer(res)
    t = table(
        "Expected standard deviation of each base parameter (SI units of the parameter)",
        ("base parameter", "CAD value", "std designed", "std best random", "ratio"),
        left=("base parameter",),
    )
    for k, name in enumerate(res.base.names):
        t.add_row(
            name,
            f"{res.base.cad[k]:.5g}",
            f"{opt.std[k]:.3g}",
            f"{best.std[k]:.3g}",
            f"{best.std[k] / opt.std[k]:.3g}x",
        )
    con.print(t)
    if res.states is not None:
        print_states(res.states, model)


def print_answer(res) -> None:
    """Which trajectory is the answer and by how much it beats the best random candidate; how each start ended."""
    import numpy as np

    con = console()
    ratio = res.best_random.std / res.optimized.std
    if res.answer == "optimized":
        con.print(
            f"the design beats the best of {res.n_candidates} random feasible trajectories: its expected std is "
            f"{np.median(ratio):.3g}x smaller in the median over the base parameters (smallest ratio "
            f"{np.min(ratio):.3g}x)",
            markup=False,
        )
    else:
        con.print(
            f"no start beat the best of {res.n_candidates} random feasible trajectories: that trajectory is the one "
            "written (more --starts or --harmonics may find a better one)",
            markup=False,
        )
    records = res.starts
    converged = sum(r.converged for r in records)
    settled = sum(r.settled for r in records)
    unsafe = sum(r.status.startswith("unsafe") for r in records)
    capped = sum(r.status.startswith("Maximum_Iterations") for r in records)
    con.print(
        f"starts: {len(records)} IPOPT runs from the best candidates: {converged} converged, {settled} settled at "
        f"the cap of {res.settings['max_iter']} iterations, {capped - settled} still improving at the cap, "
        f"{unsafe} unsafe",
        markup=False,
    )
    for k, r in enumerate(records, 1):
        con.print(
            f"  start {k}: criterion {r.start_value:.5g} -> {r.final_value:.5g}, {r.iterations} iterations, "
            f"{r.seconds:.1f} s, {r.status}",
            markup=False,
        )


def print_states(states: dict, model) -> None:
    """The joint-state errors the sensors give (rehearsed) and the noise they make, designed beside random."""
    con = console()
    opt, rnd = states["optimized"], states["random_fourier"]
    t = table(
        "Joint-state errors the sensors give (RMS over the samples, rehearsed; rad, rad/s, rad/s^2)",
        ("joint", "q", "qd designed", "qdd designed", "qd random", "qdd random"),
        left=("joint",),
    )
    for k, name in enumerate(model.joint_names):
        t.add_row(
            shown(name),
            f"{opt['rms_q'][k]:.3g}",
            f"{opt['rms_qd'][k]:.3g}",
            f"{opt['rms_qdd'][k]:.3g}",
            f"{rnd['rms_qd'][k]:.3g}",
            f"{rnd['rms_qdd'][k]:.3g}",
        )
    con.print(t)
    for label, values in (
        ("designed", opt["noise_std"]),
        ("random Fourier", rnd["noise_std"]),
        ("the optimizer's weights (first start)", states["weights_noise_std"]),
    ):
        con.print(f"noise std with the state errors, {label}: {' '.join(f'{v:.3g}' for v in values)}", markup=False)


def print_limits(res, model) -> None:
    """The bounds in force: each joint's velocity and acceleration bound and its source, the floor and box."""
    from ineid.excite.safety import bound_sources

    con = console()
    sources = bound_sources(model)
    scales = res.settings["velocity_scale"], res.settings["acceleration_scale"]
    t = table(
        f"Bounds kept at every instant (velocity x {scales[0]:g}, acceleration x {scales[1]:g} of the model's; "
        "default: no bound in the URDF, 3 rad/s and 10 rad/s^2)",
        ("joint", "position", "|qd| max", "from", "|qdd| max", "from"),
        left=("joint", "from"),
    )
    b = res.bounds
    for k, name in enumerate(model.joint_names):
        t.add_row(
            shown(name),
            f"[{b.q_lower[k]:.4g}, {b.q_upper[k]:.4g}]",
            f"{b.qd_max[k]:.4g}",
            sources[name][0],
            f"{b.qdd_max[k]:.4g}",
            sources[name][1],
        )
    con.print(t)
    s = res.safety or {"floor": None, "workspace": None, "self_collision": None}
    box, floor = s["workspace"], s["floor"]
    floor_text = "none" if floor is None else f"z >= {floor:g} m"
    box_text = (
        "none"
        if box is None
        else f"x [{box[0]:g}, {box[1]:g}], y [{box[2]:g}, {box[3]:g}], z [{box[4]:g}, {box[5]:g}] m"
    )
    line = f"floor: {floor_text}; workspace: {box_text} (base frame"
    if s.get("points"):
        line += (
            f"; kept by {', '.join(s['points'])} at every instant, {s['grid_points_per_period']} grid points per "
            f"period, at most {max(s['margin_between_samples']) * 1000:.3g} mm kept between them"
        )
    con.print(
        line
        + ")"
        + (
            ""
            if floor is not None or box is not None
            else "; --floor and --workspace keep the links above a floor and in a box"
        ),
        markup=False,
    )
    col = s["self_collision"]
    if col is None:
        con.print("self-collision: not checked (--no-self-collision)", markup=False)
    elif not col["pairs"]:
        con.print(
            "self-collision: not checked, no pair of non-adjacent bodies with collision geometry "
            f"({len(col['capsules'])} capsules)",
            markup=False,
        )
    else:
        shapes = ", ".join(f"{c['body']} ({c['shape']}, r {c['radius']:.3g} m)" for c in col["capsules"])
        counts = dict.fromkeys(col["pairs"], 0)  # a body with several capsules: its pair of bodies said once
        for pair in col["pairs"]:
            counts[pair] += 1
        named = "; ".join(pair if n == 1 else f"{pair} ({n} capsule pairs)" for pair, n in counts.items())
        con.print(
            f"self-collision: {len(col['pairs'])} pairs of bounding capsules kept apart at every instant: "
            f"{named}; capsules: {shapes}",
            markup=False,
        )
    for note in (col or {}).get("notes", []):
        con.print(f"  {note}", markup=False)
    if getattr(res, "feasibility", None) is not None:
        print_feasibility(res.feasibility)
    for where, label in (("samples", "the written samples"), ("dense", "a grid 10x denser")):
        if where in s:
            v = s[where]
            con.print(
                f"smallest clearance on {label}: {v['min_clearance'] * 1000:.4g} mm ({v['constraint']})", markup=False
            )


def print_feasibility(feas: dict) -> None:
    """The up-front check: how many sampled poses keep every bound, and what the rest pose breaks."""
    con = console()
    con.print(
        f"feasibility, checked before the design: {feas['feasible']:,} of {feas['sampled']:,} sampled poses keep "
        f"the floor, box and self-collision ({feas['seconds']:.2g} s); the rest pose (q = 0"
        + (f", {', '.join(feas['rest_clipped'])} clipped into the bounds" if feas["rest_clipped"] else "")
        + ") "
        + (f"breaks {'; '.join(feas['rest_violations'])}" if feas["rest_violations"] else "keeps them"),
        markup=False,
    )
