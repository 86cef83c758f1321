"""How far a coarse-to-fine grid grows: a final resolution that follows the steps a run will make.

A grid sized for a 5-minute CPU run (a few thousand steps) stops improving on a long run or a fast
device: ``multi`` gained 0.3 dB from 15 to 30 CPU minutes and a GPU makes 30 CPU minutes' steps in
90 seconds. More steps can fit more cells: every step updates the cells its ray samples touch, so
to give each cell as many updates as in the calibrated run, cells (resolution cubed) grow in
proportion to the steps, i.e. the resolution with their cube root.

The rule keeps every run that is predicted to make at most ``base_steps`` steps exactly as before
(``budget_resolution`` returns ``res_final`` unchanged), so short CPU runs cannot change.
"""
from __future__ import annotations

# Steps below which a run keeps its method's final resolution: above the most steps any 5-minute
# CPU run of the benchmark scenes made (5030, vmgrid on thin at 200 px, one core;
# docs/benchmarks/vmgrid200/summary.md), with room for a faster CPU.
BASE_STEPS = 8000


def budget_resolution(res_final: int, predicted_steps: float, base_steps: int = BASE_STEPS,
                      res_max: int = 320) -> int:
    """Final plane size for a run predicted to make ``predicted_steps`` optimisation steps.

    Args:
        res_final: the method's final size (cells per axis) for runs of up to ``base_steps`` steps.
        predicted_steps: steps the run will likely make (steps so far / share of the budget spent).
        base_steps: steps up to which ``res_final`` stands (<= 0: the rule is off).
        res_max: the largest size the rule may choose (never below ``res_final``).

    Returns:
        ``res_final`` when ``predicted_steps <= base_steps`` (or the rule is off); else
        ``res_final * (predicted_steps / base_steps) ** (1/3)``, rounded to a multiple of 8 and
        clamped to [res_final, max(res_final, res_max)].
    """
    if base_steps <= 0 or not predicted_steps > base_steps or res_max <= res_final:
        return int(res_final)
    grown = res_final * (predicted_steps / base_steps) ** (1.0 / 3.0)
    return int(min(res_max, max(res_final, round(grown / 8) * 8)))


def explain(res_final: int, base_steps: int = BASE_STEPS, res_max: int = 320) -> str:
    """The rule in one line, for ``--size auto``'s reasons in the ``start`` event."""
    if base_steps <= 0 or res_max <= res_final:
        return f"final grid {res_final} cells per axis whatever the budget"
    return (f"final grid follows the budget: {res_final} cells per axis for runs of up to {base_steps} steps; beyond, "
            f"{res_final} x (steps / {base_steps})^(1/3) up to {res_max}, with the steps predicted from the measured "
            "step rate when the last growth stage is due")
