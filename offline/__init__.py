"""Offline data and learners: ATAC, MAHALO and baselines (built in later milestones)."""
