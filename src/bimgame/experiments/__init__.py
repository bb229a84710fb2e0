"""Layer 5, the paper's experiment grid: budgets, the plan of pieces, running them resumably,
statistics, figures and the report."""
