"""DQN (thesis §3.1.1): SB3's DQN on Arm2D's pictures, with its settings."""
