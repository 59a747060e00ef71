"""Learners: PPO and learning from demonstrations (built in later milestones)."""
