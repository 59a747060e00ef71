"""MJX reaching environments with the brax Env API (built in the envs milestone)."""
