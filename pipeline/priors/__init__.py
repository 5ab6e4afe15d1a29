"""The shipped statistical pose prior of anny: how it is built (``cornerman priors build``)."""
