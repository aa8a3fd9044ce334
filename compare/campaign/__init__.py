"""Many runs of one scenario family: randomized scenarios from a seed, sweeps, executors."""
