"""ppd's verifier: proves protection with real SfM (pycolmap) and a CPU Gaussian splat.

Heavy imports (pycolmap, torch) live in the modules that need them and run only in
verification child processes, never in the daemon.
"""
