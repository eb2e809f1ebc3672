"""Scenario suites: a seeded generator of hazard scenarios and the Table-1 evaluation.

``spec``: the hazard file (``hazards.json``) beside each scenario, validated;
``generate``: N reproducible scenarios over a handful of netconvert-built base networks;
``evaluate``: every scenario with every planner, in fresh processes, into the paper's table.
"""
