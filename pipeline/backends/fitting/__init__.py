"""What the anny and SMPL fits share: the fit's settings (``config``: ``FitConfig``, light)
and, in torch, the one fit driver (``sequence.fit_sequence``), the protocol a body model
implements for it (``body_model.BodyModel``), the loss terms by name (``terms``), the passes
and initialisation pieces (``common``) and the overlap term between athletes (``contacts``)."""
