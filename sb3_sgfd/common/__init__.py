"""What the algorithms share: the training loop (:class:`~sb3_sgfd.common.encoder_sac.EncoderSAC`), the
encoder objectives' interface, the policies, the replay buffer, the latent dynamics of DBC and AMBS, the
argument checks and the batch transfer."""
