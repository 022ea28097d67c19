"""One mobility model (`sims.mobility`), the demo built on it, and the benchmark suites (`sims.bench`)."""
