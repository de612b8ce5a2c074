"""The replay DQN family (paper §V-B; SPEC §7): the paper's DRQN and its DQN and
frame-stacked ablations, trained by Double DQN on a whole-episode replay."""
