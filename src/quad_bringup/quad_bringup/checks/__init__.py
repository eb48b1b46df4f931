"""What is checked before anything starts: the input files (a control profile, a bag directory) and one writer per
output directory."""
