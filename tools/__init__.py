"""Research tools: every benchmark (bench) and the speed-accuracy study (study). They sit above the shell's
features, which they measure, and below the command line that runs them."""
