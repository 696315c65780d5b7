"""Report kinds over other jobs' result rows: ``report.pareto`` (error against cost, seed
spread, families, claims)."""
