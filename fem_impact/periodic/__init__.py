"""Periodic response of impacting systems: exact references for the periodic-response study.

``oscillator``: the harmonically forced impact oscillator, event-driven and exact, with its
period-1 orbit, Floquet multipliers and period-doubling frequency in closed form
(docs/impact_oscillator.md).
"""
