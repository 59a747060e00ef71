"""Learners: PPO (``agents.ppo.train``) and, later, learning from demonstrations."""
