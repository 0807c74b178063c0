"""The RL Zoo configs of TRLSD (YAML), shipped with the library: ``sb3-trlsd train`` finds them by name."""
