"""What every RL algorithm here shares: the episode replay with HER, wrappers, evaluation, saving without pickle, the curriculum, the scripted heuristic and demonstrations."""
