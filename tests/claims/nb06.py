"""Notebook 06 (the pinhole model against the paper's): what its narrative concludes, from its tables."""

from . import Tables, claim

Z_SEQUENCE = ("ZX", "ZY", "ZZ")


def check(tables: Tables, size: str) -> None:
    verdict = "ext06_pinhole_against_model2"
    tilted = tables.row(verdict, model="pinhole (tilted plate, affine)")
    within = str(tilted["within_in"]).split()
    claim(all(e in within for e in Z_SEQUENCE), verdict, "pinhole (tilted plate, affine)",
          f"the tilted-plate pinhole is within Model 2's maxima in every element of the Z sequence (within: {within})")
    claim(tilted["worst_max_abs_um"] < tilted["paper-m2_worst_max_abs_um"], verdict, "pinhole (tilted plate, affine)",
          f"the tilted-plate pinhole's worst element ({tilted['worst_max_abs_um']:.1f} um) is below Model 2's "
          f"({tilted['paper-m2_worst_max_abs_um']:.1f} um)")
    stage = tables.row(verdict, model="pinhole (stage views, affine)")
    claim(stage["worst_max_abs_um"] > 2 * stage["paper-m2_worst_max_abs_um"], verdict, "pinhole (stage views, affine)",
          "the paper's conclusion holds from the stage views: the pinhole's worst element is over twice Model 2's")
    claim(stage["worst_element"] == "XZ", verdict, "pinhole (stage views, affine)",
          f"E_X,Z is the stage-view pinhole's weak point (worst: {stage['worst_element']})")
    rigid = tables.row(verdict, model="pinhole (stage views, rigid)")
    claim(rigid["worst_max_abs_um"] > stage["worst_max_abs_um"], verdict, "pinhole (stage views, rigid)",
          "a rigid camera-to-stage map (the pinhole's own metric scale) is worse than the affine one")
    zz = tables.value("ext06_model_comparison", "trend_um_per_mm", model="pinhole (stage views, rigid)", element="ZZ")
    claim(abs(zz) > 100, "ext06_model_comparison", "pinhole (stage views, rigid), ZZ",
          f"the pinhole's own depth scale is wrong by more than 10 % ({zz / 10:+.0f} %)")

    comparison = "ext06_model_comparison"
    m2 = tables(comparison)
    m2 = m2[m2["model"] == "paper-m2"].set_index("element")
    claim((m2.loc[[e for e in m2.index if e[1] != "Z"], "S_RA3_percent"] >= 95).all()
          and (m2.loc[[e for e in m2.index if e[1] == "Z"], "S_RA5_percent"] >= 95).all(), comparison, "paper-m2",
          "Model 2 (notebook 05's calibration and validation run) meets the paper's requirement in every element")

    sens = tables("ext06_pinhole_sensitivity_to_views")
    claim((sens["largest_element"] == "XZ").all(), "ext06_pinhole_sensitivity_to_views", "every test",
          "E_X,Z is the largest element from every test's views")
    if size == "full":
        xz = sens["max_abs_E_XZ_um"]
        claim(xz.max() > 1.5 * xz.min(), "ext06_pinhole_sensitivity_to_views", "every test",
              f"what OpenCV converges to depends on the views: E_X,Z from {xz.min():.0f} to {xz.max():.0f} um")
