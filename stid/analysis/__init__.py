"""Where a model fails: residual analysis, noise floor, comparison by band, |ay| and run."""
