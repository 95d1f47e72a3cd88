"""Notebook 03: Eqs 13-16 read jointly, the single pass's attenuation, the vertex condition, Table 2."""

from __future__ import annotations

from . import Tables, claim


def check(t: Tables, size: str) -> None:
    name = "ext03_path_straightness"
    s = t(name).set_index("disparity")["rms_off_straight_px"]
    claim(s["joint"] < 0.1 < 0.5 < s["raw"], name, "joint", "the joint fit's correction leaves the paths straight (the parabola gone)")
    claim(s["single-pass"] > 5 * s["joint"], name, "single-pass", "the single pass leaves the paths curved")

    name = "ext03_recovered_share"
    r = t(name)
    test1 = t.row(name, positions_X=42, pitch_mm=0.3)
    claim(test1["recovered_share"] < 0.5, name, "42, 0.3", "on Test 1's layout one pass recovers under half of the curvature")
    claim((r["recovered_share"] - r["predicted_share"]).abs().max() < 0.03, name, "all",
          "the pooled-regression attenuation predicts the share within 3 points")

    name = "ext03_vertex_check"
    v = t(name)
    paper = v[v["source"].str.startswith("paper")].iloc[0]
    joint = v[v["source"].str.contains("joint")].iloc[0]
    single = v[v["source"].str.contains("single")].iloc[0]
    claim(abs(paper["relative_difference"]) < 0.002, name, "paper", "the paper's Table 2 obeys cD = bD²/(4·aD) to 0.1 %")
    claim(joint["relative_difference"] == 0, name, "joint", "the joint fit sets cD at the vertex")
    claim(abs(single["relative_difference"]) > 0.05, name, "single pass", "a single pass's quadratic does not obey it")

    name = "table2_alignment_disparity"
    t2 = t(name).set_index("parameter")
    for p in ("alpha_deg", "dw2_px", "aD", "bD", "cD_px"):
        claim(abs(t2.loc[p, "ours_vs_paper_percent"]) < 0.5, name, p, "within 0.5 % of the paper's (by construction)")
    for p in ("alpha_deg", "dw2_px"):
        ratio = t2.loc[p, "ours_std_within_run"] / t2.loc[p, "paper_pm"]
        claim(0.5 < ratio < 2, name, p, "the paper's ± is of the order of our spread within one run")
        claim(t2.loc[p, "ours_std_over_runs"] < t2.loc[p, "paper_pm"] / 10, name, p, "and far above our spread over runs")
    for p in ("aD", "bD", "cD_px"):
        ours = t2.loc[p, "ours_std_over_runs"] / abs(t2.loc[p, "ours_mean"])
        claim(ours < t2.loc[p, "paper_pm"] / abs(t2.loc[p, "paper"]), name, p,
              "our spread over runs is below the paper's ± (relative)")
