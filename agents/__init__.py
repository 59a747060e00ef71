"""Learners: PPO (``agents.ppo``) and, later, learning from demonstrations."""
