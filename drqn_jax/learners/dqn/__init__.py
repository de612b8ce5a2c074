"""The paper's DRQN and its ablations by Double DQN on a whole-episode replay (§V-B; SPEC §7)."""
