"""Notebook 12 (your microscope): the example folder goes from images to 3D as the narrative says."""

from . import Tables, claim

XYZ = "XYZ"


def check(tables: Tables, size: str) -> None:
    ext = tables("ext12_extraction")
    for _, r in ext.iterrows():
        claim(r["found_and_indexed_percent"] >= 99.9 and r["misindexed"] == 0, "ext12_extraction", r["run"],
              "every visible dot found and numbered right")
        claim(r["rms_in_focus_px"] <= 0.05, "ext12_extraction", r["run"], "centres within 0.05 px RMS in focus")
    ev = tables("ext12_evaluation").set_index("element")
    passes = [(ev.loc[e, "S_RA5_percent"] if e[1] == "Z" else ev.loc[e, "S_RA3_percent"]) >= 95 for e in ev.index]
    claim(all(passes), "ext12_evaluation", "every element", "the model meets the paper's requirement on the check run")
    rec = tables("ext12_reconstruction").set_index("coordinate")
    claim((rec["rms_error_um"] < 1.0).all(), "ext12_reconstruction", "X, Y, Z", "reconstruction errors below 1 um RMS")
    claim(rec.loc["X", "inside_95_percent"] >= 93, "ext12_reconstruction", "X", "the X intervals hold their share")
