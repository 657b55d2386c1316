"""Where a model fails: residual analysis, the noise floor (what a correct model reaches),
the evidence an effect must show before it is named, and what stays unexplained."""
