"""Notebook 07 (micro-gripping): the target and how the loop depends on the model, from its episodes table."""

from . import Tables, claim

TABLE = "ext07_gripping_episodes"
TARGET_OFFSET_UM = 10.0


def check(tables: Tables, size: str) -> None:
    t = tables(TABLE)
    default = t.iloc[0]  # the notebook puts the default model first
    claim(default["final_offset_max_um"] <= TARGET_OFFSET_UM, TABLE, default["model"],
          f"the default closes within {TARGET_OFFSET_UM} um in every episode ({default['final_offset_max_um']:.2f} um at worst)")
    claim(default["success_rate"] == 1.0, TABLE, default["model"], "the default grips in every episode")
    m0 = tables.row(TABLE, model="paper-m0")
    claim(m0["final_offset_max_um"] < m0["tip_error_mean_um"], TABLE, "paper-m0",
          "what Model 0 gets wrong over the workspace cancels in the loop: it closes nearer than it reconstructs the tip")
    claim(m0["pad_offset_mean_um"] > default["pad_offset_mean_um"], TABLE, "paper-m0",
          "the model matters for the open-loop drag: Model 0 releases the wire farther from the pad's centre")
