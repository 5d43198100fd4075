"""The training vocabulary, without torch (the command line offers it before torch is imported):
the losses and optimizers dc train and dc study maps take."""

LOSSES = ("masked", "contacts", "mse", "solver")
OPTIMIZERS = ("sgd", "adam")
