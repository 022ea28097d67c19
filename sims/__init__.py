"""Entity behaviours, load simulations and benchmark suites."""
