"""Training the network: loss, augmentations, optimiser, resumable loop (``loop``) and its data (``data``)."""
