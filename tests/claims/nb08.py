"""Notebook 08 (the explorers): each explorer, driven from code, responds as the narrative says."""

from . import Tables, claim

TABLE = "ext08_explorer_responses"


def check(tables: Tables, size: str) -> None:
    r = tables.row(TABLE, explorer="microscope")
    claim(1.8 <= r["after_over_before"] <= 2.2, TABLE, "microscope",
          f"doubling the decentred distortion about doubles aD (x{r['after_over_before']:.2f})")
    r = tables.row(TABLE, explorer="models")
    claim(r["after"] > r["before"], TABLE, "models", "Model 1 raises S_Y,X at RA3 over Model 0")
    r = tables.row(TABLE, explorer="steps")
    claim(r["after"] > r["before"], TABLE, "steps", "fewer positions spread EZ more over repeated calibrations")
