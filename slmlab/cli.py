"""The command line: ``python -m slmlab VERB ...`` (README, "The virtual microscope from the command line").

Verbs: ``simulate``, ``extract``, ``models``, ``calibrate``, ``reconstruct``, ``evaluate``, ``grip``, ``bench``,
``data``.
Every error a user can cause ends with exit status 2 and one line on stderr; outputs are written
atomically.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np

from . import datasets
from .bench import run as run_bench
from .errors import SlmlabError
from .gripping import grip
from .images.centres import METHODS
from .images.imageset import extract_set
from .io import IMAGE_COLUMNS, TARGET_COLUMNS, atomic_folder, read_points, read_set, write_csv, write_set
from .models import available_models, calibrate, default_model_name, get_model_class, load_model
from .models.auto import selection_table
from .paper.evaluation import evaluate
from .studies.extraction import extraction_errors, extraction_summary
from .target_check import check_target
from .virtual.designs import DESIGNS, simulate_design
from .virtual.presets import preset
from .virtual.render import check_renderable, render_set, truth_places_held
from .virtual.rigs import rig_by_name
from .virtual.sessions import paper_test, validation_session
from .virtual.simulate import simulate_set

EXIT_USER_ERROR = 2


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr and exit status 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        command = " ".join(filter(None, ["python -m slmlab", self._verb()]))
        self.exit(EXIT_USER_ERROR, f"slmlab: error: {message} (see '{command} --help')\n")

    def _verb(self) -> str:
        parts = self.prog.split()
        return " ".join(parts[parts.index("slmlab") + 1:]) if "slmlab" in parts else ""


def _seed(text: str) -> int:
    """A seed: a whole number, 0 or more (NumPy's generators take no negative seed)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"invalid seed {text!r}: a whole number, 0 or more")
    return value


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m slmlab", description="Stereo light microscope vision modelling workbench.")
    sub = p.add_subparsers(dest="verb", required=True, parser_class=_Parser)

    s = sub.add_parser("simulate", help="write a simulated calibration set (with truth.csv) from a virtual instrument")
    s.add_argument("out_dir", type=Path)
    s.add_argument("--preset", default=None, help="virtual CMO microscope preset (paper, leica, ideal; default paper)")
    s.add_argument("--rig", default=None, help="a virtual rig instead of the CMO microscope: greenough, stereo-dic, "
                   "stereo-piv, or KIND:SEED for one drawn at random (e.g. stereo-piv:7); needs --design")
    s.add_argument("--design", default=None, help="what the rig images: zstack-2 ... zstack-13, stage-sequences, "
                   "stepped-target, two-level, two-level-2z, two-level-3z, charuco-stack")
    s.add_argument("--seed", type=_seed, default=0)
    s.add_argument("--images", action="store_true", help="also render every stereo pair as PNG (a rig's with its "
                   "camera's degradations, and a stage.csv naming them; not the stepped target)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--test", type=int, default=None, help="calibration test 1-5 of the paper's Table 3 (default 1)")
    g.add_argument("--validation", action="store_true", help="the §6 validation run instead of a calibration test")

    e = sub.add_parser("extract", help="find and index the dots in images/ and write points.csv")
    e.add_argument("cal_dir", type=Path)
    e.add_argument("--method", default="auto", choices=["auto", *METHODS],
                   help="sub-pixel centre estimator of dot plates (auto: chosen per plate and view, see the notes)")

    sub.add_parser("models", help="list the vision models")

    c = sub.add_parser("calibrate", help="fit a vision model on a calibration set")
    c.add_argument("cal_dir", type=Path)
    c.add_argument("--model", default=None, help="model name (default: the most accurate)")
    c.add_argument("--out", type=Path, required=True, help="model file to write (JSON)")
    c.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                   help="a model option, repeatable (e.g. length_reference=plate, stage_scale_sigma=1e-4, degree=3)")

    r = sub.add_parser("reconstruct", help="world coordinates of image points with a model file")
    r.add_argument("model", type=Path)
    r.add_argument("points", type=Path)
    r.add_argument("--out", type=Path, required=True)

    v = sub.add_parser("evaluate", help="residual elements, RA1-RA5 and S coefficients of a model on a set")
    v.add_argument("model", type=Path)
    v.add_argument("cal_dir", type=Path)
    v.add_argument("--json", action="store_true")

    gr = sub.add_parser("grip", help="one micro-gripping episode on the virtual microscope (paper §2)")
    gr.add_argument("--seed", type=_seed, default=0)
    gr.add_argument("--model", default=None, help="vision model (default: the most accurate)")
    gr.add_argument("--json", action="store_true", help="print the result as one JSON line (last)")

    b = sub.add_parser("bench", help="speed benchmarks beside the field's reference implementations")
    b.add_argument("--json", action="store_true")
    b.add_argument("--markdown", type=Path, default=None, help="also write the table as Markdown (table6_speed.md)")
    b.add_argument("--reproduce-seconds-file", type=Path, default=None, help="a file holding make reproduce's time")

    d = sub.add_parser("data", help="the third-party datasets: list them, fetch them into the cache (SHA-256 checked)")
    dsub = d.add_subparsers(dest="data_verb", metavar="{fetch,list}", required=True, parser_class=_Parser)
    df = dsub.add_parser("fetch", help="fetch datasets into the cache and check every file (all when none named)")
    df.add_argument("names", nargs="*", metavar="NAME", help="dataset name (see 'python -m slmlab data list')")
    dsub.add_parser("list", help="each dataset: files, size, whether it is cached, where it comes from")
    return p


# ------------------------------------------------------------------------------------------------ verbs
def _simulate(a) -> int:
    if (a.rig is None) != (a.design is None):
        raise SlmlabError("--rig and --design go together: a rig (greenough, stereo-dic, stereo-piv) and what it "
                          f"images ({', '.join(DESIGNS)})")
    if a.rig is not None:
        given = [f"--{k}" for k in ("preset", "test") if getattr(a, k) is not None] + ["--validation"] * a.validation
        if given:   # the CMO microscope's options: a rig would have ignored them
            raise SlmlabError(f"{given[0]} is the CMO microscope's; a rig's set is chosen by --rig and --design alone")
        cal = simulate_design(rig_by_name(a.rig), a.design, seed=a.seed)
    else:
        session = validation_session() if a.validation else paper_test(1 if a.test is None else a.test)
        cal = simulate_set(preset(a.preset or "paper"), session, seed=a.seed)
    if a.images:
        check_renderable(cal)
    with atomic_folder(a.out_dir) as folder:   # whole or not at all; an old simulated set replaced only then
        write_set(folder, cal)
        written = render_set(cal, folder) if a.images else []
    n = cal.points[["wl1", "wr1"]].notna().all(axis=1).sum()
    print(f"wrote {a.out_dir}: {len(cal.points)} rows ({n} seen in both views), "
          f"sequences {', '.join(cal.sequences)}")
    if a.images:
        print(f"rendered {len(written)} images into {a.out_dir / 'images'}")
    return 0


def _extract(a) -> int:
    points, notes = extract_set(a.cal_dir, method=a.method)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    try:   # the points.csv this replaces: only a simulated set's comparison with truth.csv reads it
        old = read_set(a.cal_dir) if (a.cal_dir / "points.csv").exists() else None
    except SlmlabError as exc:
        old = None
        print(f"note: the points.csv replaced could not be read ({exc.reason}); nothing compared with it",
              file=sys.stderr)
    write_csv(a.cal_dir / "points.csv", points)
    n_both = int(points[["wl1", "wr1"]].notna().all(axis=1).sum())
    print(f"wrote {a.cal_dir / 'points.csv'}: {len(points)} dots ({n_both} in both views)")
    if old is not None and old.truth is not None and "simulator" in old.meta:
        if not truth_places_held(old):   # the comparison only: the points are written
            print("note: not compared with truth.csv: points.csv was not the simulated one (written by extract "
                  "before?), which held the true places of the target's dots; simulate the set again", file=sys.stderr)
            return 0
        s = extraction_summary(extraction_errors(points, old))
        print(f"against truth.csv: {s['found_and_indexed_percent']:.2f} % of {s['visible']} visible dots found and "
              f"indexed, {s['misindexed']} misindexed; centre RMS {s['rms_in_focus_px']:.4f} px in focus, "
              f"{s['rms_depth_of_field_px']:.4f} px over the depth of field")
    return 0


def _models(a) -> int:
    for name, cls in available_models().items():
        print(f"{name}\t{cls.summary}")
    return 0


def _not_an_input(out: Path, inputs: list[Path]) -> None:
    """:class:`SlmlabError` where ``--out`` is one of the command's own input files (a model written over the set's
    ``points.csv`` had replaced it, and the set could not be read again)."""
    same = [f for f in inputs if f.exists() and out.exists() and os.path.samefile(out, f)]
    if same:
        raise SlmlabError(f"--out is the input {same[0].name}, which this would overwrite; choose another --out", out)


def _calibrate(a) -> int:
    if not a.out.parent.exists():
        raise SlmlabError(f"the folder {a.out.parent} does not exist; create it or choose another --out", a.out)
    _not_an_input(a.out, [a.cal_dir / n for n in ("points.csv", "stage.csv", "meta.json", "truth.csv")])
    options = _model_options(a.model, a.option)
    cal = read_set(a.cal_dir)
    model = calibrate(cal, a.model, **options)
    model.save(a.out)
    for note in cal.notes:
        print(f"note: {note}", file=sys.stderr)
    suspects = model.calibration.get("suspect_rows") or []
    if suspects:
        shown = ", ".join(f"{q['sequence']} position {q['position']} dot [{q['row']},{q['col']}] "
                          f"({1e3 * q['residual_mm']:.0f} um)" for q in suspects[:5])
        print(f"note: {len(suspects)} row(s) look misindexed or mismatched (kept; listed in the model file under "
              f"calibration.suspect_rows): {shown}{' ...' if len(suspects) > 5 else ''}", file=sys.stderr)
    dropped = model.calibration.get("down_weighted_rows") or []
    if dropped:
        print(f"note: {len(dropped)} row(s) rejected as outliers (listed in the model file under "
              f"calibration.down_weighted_rows)", file=sys.stderr)
    print(f"wrote {a.out} (model {model.name})")
    return 0


def _model_options(name: str | None, pairs: list[str]) -> dict:
    """``NAME=VALUE`` pairs as keyword options of the model's ``fit`` (values read as JSON where they parse,
    else as text); an option the model does not take is an error."""
    cls = get_model_class(name or default_model_name())
    known = [p.name for p in inspect.signature(cls.fit).parameters.values()
             if p.kind is inspect.Parameter.KEYWORD_ONLY]
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key not in known:
            raise SlmlabError(f"--option {pair!r}: model {cls.name!r} takes "
                              f"{', '.join(k + '=...' for k in known) or 'no options'}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _reconstruct(a) -> int:
    _not_an_input(a.out, [a.model])   # the points' own file it may replace: every column passes through
    model = load_model(a.model)
    df = read_points(a.points)
    w = df[IMAGE_COLUMNS].to_numpy(float)
    xyz = np.full((len(w), 3), np.nan)
    ok = np.isfinite(w).all(axis=1)
    xyz[ok] = model.reconstruct(w[ok])
    for k, c in enumerate(("X_mm", "Y_mm", "Z_mm")):
        df[c] = xyz[:, k]
    empty = []
    if hasattr(model, "uncertainty"):  # 1-sigma per point, where the model provides it
        sig = np.full((len(w), 3), np.nan)
        sig[ok] = model.uncertainty(w[ok])
        for k, c in enumerate(("sX_mm", "sY_mm", "sZ_mm")):
            df[c] = sig[:, k]
        empty = [c for k, c in enumerate(("sX_mm", "sY_mm", "sZ_mm")) if ok.any() and not np.isfinite(sig[ok, k]).any()]
    write_csv(a.out, df)
    print(f"wrote {a.out}: {int(ok.sum())} of {len(w)} points reconstructed with {model.name}")
    if empty:   # a coordinate the default took from a model without one (the pinhole pair)
        print(f"note: {', '.join(empty)} left empty: the model gives no per-point uncertainty there")
    return 0


def _evaluate(a) -> int:
    model = load_model(a.model)
    cal = read_set(a.cal_dir)
    for note in cal.notes:
        print(f"note: {note}", file=sys.stderr)
    table = selection_table(model)
    ev = _evaluation(model, cal)
    if a.json:
        print(json.dumps({**ev.as_json(), "selection": model.calibration.get("selection")}, indent=2))
        return 0
    if table is not None:  # the default's choice first: it is in the model file, whatever the set evaluated
        sel = model.calibration["selection"]
        print(f"the default's choice ({sel['held_out_by']}; {sel['rule']}):")
        print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        for label, why in sel.get("skipped", {}).items():
            print(f"  not a candidate: {label}: {why}")
        if stage := sel.get("stage"):  # the stage's own errors (slmlab.models.stage_errors)
            print(f"  stage positions {'corrected' if stage['applied'] else 'as commanded'}: {stage['why']}")
        print()
    print(ev.text())
    return 0


def _evaluation(model, cal):
    """The paper's evaluation on the set's stage sequences (§5.2-§5.3); on a known-target set without them, the
    target's shape (:func:`slmlab.target_check.check_target`)."""
    try:
        return evaluate(model, cal)
    except SlmlabError:
        if not set(TARGET_COLUMNS) <= set(cal.points.columns):
            raise
        return check_target(model, cal)


def _grip(a) -> int:
    name = a.model or default_model_name()
    get_model_class(name)  # unknown names are a user error before any work
    ep = grip(a.seed, name)
    d = {"model": name, "seed": a.seed, **ep.as_dict()}
    if not a.json:
        print(f"model {name}, seed {a.seed}: {'gripped' if ep.gripped else 'NOT gripped'} after {ep.iterations} looks; "
              f"final offset {ep.final_offset_um:.2f} um; reconstruction errors tip {ep.tip_error_um:.2f} um, "
              f"gripping position {ep.target_error_um:.2f} um; released {ep.pad_offset_um:.2f} um from the pad centre")
    print(json.dumps(d))
    return 0


def _bench(a) -> int:
    return run_bench(as_json=a.json, markdown_path=a.markdown, reproduce_seconds_file=a.reproduce_seconds_file)


def _data(a) -> int:
    if a.data_verb == "list":
        table = datasets.status()
        print(f"cache: {datasets.cache_dir()}")
        print(table.drop(columns="title").to_string(index=False))
        return 0
    for name in a.names:
        datasets.dataset(name)                      # every name checked before anything is fetched
    for name in a.names or datasets.names():
        ds = datasets.dataset(name)
        folder = datasets.fetch(name)
        print(f"{name}: {len(ds.files)} files, {ds.size_bytes / 1e6:.1f} MB, SHA-256 checked, in {folder}")
    return 0


VERBS = {"simulate": _simulate, "extract": _extract, "models": _models, "calibrate": _calibrate,
         "reconstruct": _reconstruct, "evaluate": _evaluate, "grip": _grip, "bench": _bench, "data": _data}


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit status (0 success, 2 user error)."""
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # our errors are one line; OpenCV's are not
    args = _parser().parse_args(argv)
    try:
        return VERBS[args.verb](args)
    except SlmlabError as exc:
        if exc.path is None and _input_of(args) is not None:  # every message names the file it is about
            exc = SlmlabError(exc.reason, _input_of(args))
        print(f"slmlab: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:  # the system refused a folder or a file (no permission, no space, /proc)
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"slmlab: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USER_ERROR


def _input_of(args):
    """The file or folder a verb reads (to name in an error that does not say where)."""
    for name in ("cal_dir", "points", "model"):
        value = getattr(args, name, None)
        if isinstance(value, Path):
            return value
    return None
