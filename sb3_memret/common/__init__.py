"""What every layer may use and none owns: errors, seeds, the cache folder, observation trees, the run logger, strict
weight checks, the CPU renderer's set-up and worker processes."""
