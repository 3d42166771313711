"""Package data: the shipped experiment CSV and the models identified from it (see `czmpc.shipped`)."""
