"""What the runs show: ``evaluate`` (``sgfd-zoo evaluate``: every final model on every split, the paper's tables),
``statistics`` (scores, rliable's aggregates with confidence intervals, their figures) and ``plot`` (``sgfd-zoo
plot``: learning curves). Reading and plotting import no torch; evaluating a model loads it."""
