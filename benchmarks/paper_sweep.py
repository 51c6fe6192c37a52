"""The sweep behind docs/learning.md "What to expect": the paper's dataset and split.

Run: ``python benchmarks/paper_sweep.py OUT_DIR`` (about 25 minutes on a 2-core CPU). Each
run trains into ``OUT_DIR/<name>_<loss>`` and appends one JSON line with its test errors,
the null-space floor and the linear least squares to ``OUT_DIR/results.jsonl``.
"""
import json
import sys
import time
from pathlib import Path

import ineid
from ineid.data import DatasetSpec, generate_dataset
from ineid.learn import ModelSpec, TrainConfig, evaluate, load_run, train

OUT = Path(sys.argv[1] if len(sys.argv) > 1 else "paper_sweep")
OUT.mkdir(parents=True, exist_ok=True)
m = ineid.load_robot("sweaty-arm")
ds = generate_dataset(m, DatasetSpec(seed=0))   # the paper's 10,000 configurations x 100 frames
out = open(str(OUT / "results.jsonl"), "a")
S = dict(batch=1024, lr=1e-3)
runs = [
    ("simple", ModelSpec("simple"), "mse", dict(epochs=100, patience=15, batch=256, lr=1e-3)),
    ("simple", ModelSpec("simple"), "physics", dict(epochs=100, patience=15, batch=256, lr=1e-3, beta=50.0)),
    ("net1", ModelSpec("net1"), "mse", dict(epochs=30, patience=8, **S)),
    ("net2", ModelSpec("net2"), "mse", dict(epochs=30, patience=8, **S)),
    ("net3", ModelSpec("net3"), "mse", dict(epochs=30, patience=8, **S)),
    ("net4", ModelSpec("net4"), "mse", dict(epochs=30, patience=8, **S)),
    ("net5", ModelSpec("net5"), "mse", dict(epochs=30, patience=8, **S)),
    ("funnel", ModelSpec("funnel"), "mse", dict(epochs=30, patience=8, **S)),
    ("multi net2 K10", ModelSpec("net2", frames=10), "mse", dict(epochs=100, patience=15, batch=64, lr=1e-3)),
    ("multi net5 K10", ModelSpec("net5", frames=10), "mse", dict(epochs=100, patience=15, batch=64, lr=1e-3)),
    ("multi net2 K10", ModelSpec("net2", frames=10), "physics", dict(epochs=100, patience=15, batch=64, lr=1e-3, beta=50.0)),
    ("siamese net2 K10", ModelSpec("net2", frames=10, siamese=True), "mse", dict(epochs=100, patience=15, batch=64, lr=1e-3)),
    ("siamese net2 K10", ModelSpec("net2", frames=10, siamese=True), "physics", dict(epochs=100, patience=15, batch=64, lr=1e-3, beta=50.0)),
    ("net6", ModelSpec("net6"), "mse", dict(epochs=10, patience=5, **S)),
    ("siamese net6 K10", ModelSpec("net6", frames=10, siamese=True), "mse", dict(epochs=40, patience=10, batch=64, lr=1e-3)),
    ("net7", ModelSpec("net7"), "mse", dict(epochs=5, patience=5, **S)),
]
for name, spec, loss, kw in runs:
    cfg = TrainConfig(model=spec, loss=loss, scaler="robust", optimizer="adam", n_train=3000, n_val=500, n_test=500, seed=0, **kw)
    t = time.perf_counter()
    slug = name.replace(" ", "_")
    d = str(OUT / f"{slug}_{loss}")
    r = train(ds, cfg, d, overwrite=True, model=m)
    ev = evaluate(load_run(d), ds, model=m)
    rec = dict(name=name, loss=loss, epochs=r.epochs_run, best_epoch=r.best_epoch, stopped=r.stopped_early, seconds=time.perf_counter() - t,
               standard=ev.network["overall_median"], base=ev.network_base["overall_median"],
               floor=ev.floor["overall_median"], linear_standard=ev.linear["overall_median"],
               linear_base=ev.linear_base["overall_median"], physical=ev.physical_share,
               linear_physical=ev.linear_physical_share, per_sample=ev.per_sample_median,
               mass_r2=ev.network_base["r2"][0], frames=ev.frames_used)
    out.write(json.dumps(rec) + "\n"); out.flush()
    print(rec, flush=True)
