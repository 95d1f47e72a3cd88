"""Notebook 09 (beyond the paper): the targets it sets itself and the explanations it draws, from its tables."""

from . import Tables, claim

FLOOR = 1.2
XYZ = "XYZ"


def _worst(row, suffix="_vs_floor") -> float:
    return max(row[f"{c}{suffix}"] for c in XYZ)


def _preset(tables: Tables) -> str:
    return next(m for m in tables("ext09_volumetric_comparison")["microscope"].unique() if m != "perfect stage")


def check(tables: Tables, size: str) -> None:
    preset = _preset(tables)
    vc = "ext09_volumetric_comparison"
    perfect = tables.row(vc, microscope="perfect stage", model="default (auto)")
    claim(_worst(perfect) <= FLOOR, vc, "perfect stage, default (auto)",
          f"on a perfect stage the default is within {FLOOR} x the floor in X, Y, Z ({_worst(perfect):.2f})")
    ours = tables.row(vc, microscope=preset, model="default (auto)")
    claim(max(ours["X_vs_floor"], ours["Y_vs_floor"]) > FLOOR, vc, f"{preset}, default (auto)",
          "the target is not met on the preset's stage in X or Y (the notebook says so)")
    limit = tables.row("ext09_commanded_frame_limit", microscope=f"{preset}")
    claim(min(limit["X_attainable_vs_floor"], limit["Y_attainable_vs_floor"]) > FLOOR, "ext09_commanded_frame_limit",
          preset, "the commanded frame alone is above the target in X and Y: no model on these moves can meet it")
    t = tables(vc)
    paper = t[(t["microscope"] == preset) & t["model"].str.startswith("paper-")]
    claim((paper[[f"{c}_vs_floor" for c in XYZ]] > 5).all().all(), vc, f"{preset}, paper-m*",
          "the paper's models are many times above the floor in every coordinate")

    cov = "ext09_uncertainty_coverage"
    claim(bool(tables.row(cov, microscope="perfect stage", calibration="X, Y, Z sequences (Test 1)")["within 95 ± 2 %"]),
          cov, "perfect stage, three axes", "with a perfect stage the 95 % intervals hold 95 +- 2 %")
    claim(not bool(tables.row(cov, microscope=preset, calibration="X, Y, Z sequences (Test 1)")["within 95 ± 2 %"]),
          cov, f"{preset}, three axes", "on the preset's stage the intervals do not hold (the stage's own errors)")

    cv = tables("ext09_cross_validation_diff").set_index(["microscope", "coordinate"])
    ratio = cv.loc[("perfect stage", "X"), "rms_diff_um"] / cv.loc[(preset, "X"), "rms_diff_um"]
    if ratio > 2:
        claim(cv.loc[("perfect stage", "X"), "settings_a"] != cv.loc[("perfect stage", "X"), "settings_b"],
              "ext09_cross_validation_diff", "perfect stage, X",
              f"the perfect stage's larger difference (x{ratio:.0f}) comes with different settings chosen by the two calibrations")

    zs = tables.row("ext09_zstack_calibration", microscope="perfect stage", calibration="Z stack alone")
    claim(_worst(zs) <= FLOOR, "ext09_zstack_calibration", "perfect stage, Z stack alone",
          "a Z stack alone is a complete calibration on a perfect stage")

    rob = tables.row("ext09_robustness", model="default, corrupted rows")
    claim(rob["rejected_and_corrupted"] == rob["corrupted_rows"], "ext09_robustness", "default, corrupted rows",
          "the default rejects every corrupted row")
    claim(_worst(rob) <= 2.0, "ext09_robustness", "default, corrupted rows", "with corrupted rows it stays within 2 x the floor")

    _positions(tables)
    _real_zstack(tables)


def _positions(tables: Tables) -> None:
    name = "ext09_accuracy_vs_positions"
    t = tables(name)
    for case, g in t[t["model"] == "paper-m2"].groupby("case"):
        spread = (g[[f"{c}_vs_floor" for c in XYZ]].max() / g[[f"{c}_vs_floor" for c in XYZ]].min()).max()
        claim(spread <= 1.2, name, f"{case}, paper-m2", f"the paper's model is flat over the thinnings ({spread:.2f})")
    for case, g in t[t["model"] == "direct"].groupby("case"):
        g = g.sort_values("positions").reset_index(drop=True)
        for k in range(1, len(g) - 1):
            row, nb = g.loc[k], g.loc[[k - 1, k + 1]]
            if any(row[f"{c}_vs_floor"] > 1.3 * nb[f"{c}_vs_floor"].max() for c in XYZ):
                claim(row["settings"] not in set(nb["settings"]), name, f"{case}, {row['positions']} positions",
                      "a jump above both neighbours comes with another choice of degrees or variables than theirs")


def _real_zstack(tables: Tables) -> None:
    name = "ext09_real_zstack_lopo"
    if not (tables.folder / f"{name}.csv").exists():  # the real data could not be fetched: the notebook says so
        return
    t = tables(name)
    for label, prefix in (("default (auto)", "auto"), ("direct", "direct"), ("direct, degree 2", "direct"),
                          ("direct, degree 1 (linear)", "direct"), ("soloff", "soloff")):
        settings = t[t["model"] == label]["settings"]
        claim(len(settings) and settings.str.startswith(prefix).all(), name, label, f"the rows labelled {label!r} run {prefix}")
    claim(t[t["model"] == "direct, degree 1 (linear)"]["settings"].str.contains("degrees 1/1/1").all(), name,
          "direct, degree 1 (linear)", "the linear rows are degree 1")
    claim(t[t["model"] == "direct, degree 2"]["settings"].str.contains("degrees 2/2/2").all(), name, "direct, degree 2",
          "the degree-2 rows are degree 2")
    s = tables("ext09_real_zstack_lopo_summary").set_index("model")
    claim(all(s.loc["direct, degree 1 (linear)", f"{c}_um"] > 2 * s.loc["direct", f"{c}_um"] for c in XYZ),
          "ext09_real_zstack_lopo_summary", "direct, degree 1 (linear)",
          "a linear map leaves several times the polynomial's left-out error in X, Y and Z")
