"""The survival instinct of offline RL (thesis chapter 8, docs/design.md §2.4): wrong rewards and
length bias (:mod:`offline.survival.rewards`), the eq 8.3 estimate, the rewards × seeds sweep, the
tabular grid world of Fig. 8.2, collision-margin filtering and the chapter-8 reproduction."""
