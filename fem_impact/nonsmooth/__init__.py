"""The nonsmooth layer: the contact relation (P, d0, rows), contact laws, the one-step contact problem."""
