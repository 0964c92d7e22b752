"""The ambiguity manager: when tracking can't be trusted, global localization, and back.

* :mod:`~fusion.ambiguity.manager` — the state machine (:class:`AmbiguityManager`): every
  transition and what it resets;
* :mod:`~fusion.ambiguity.tracking` — while tracking: the evidence for giving tracking up (the
  verdict on each fix is the decision stage's, :mod:`fusion.decision`);
* :mod:`~fusion.ambiguity.relocalization` — while not: views, global matches, followed poses;
* :mod:`~fusion.ambiguity.fit` — how well a scan lies on the walls, the measure it judges by;
* :mod:`~fusion.ambiguity.local_search` — a pose near the guess after a slip;
* :mod:`~fusion.ambiguity.views` — the views collected for a global match;
* :mod:`~fusion.ambiguity.spacing` — the line spacing that bounds a trusted covariance;
* :mod:`fusion.settings.ambiguity` — its settings (apart, so that a configuration is read
  without loading the manager).
"""
