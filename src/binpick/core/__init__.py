"""What every part of binpick stands on: errors that print as one line, files written atomically and
read with limits, validated configs, run folders and checkpoints, weights as safetensors."""
