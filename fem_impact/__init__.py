"""fem-impact: dynamics of elastic structures with unilateral constraints (impacts), on FEniCSx."""

__version__ = "0.1.0"
