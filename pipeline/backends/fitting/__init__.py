"""What the anny and SMPL fits share: the fit's settings (``config``: ``FitConfig``, light)
and, in torch, the sequence terms and passes (``common``) and the overlap term between
athletes (``contacts``)."""
