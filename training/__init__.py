"""Lightning training of the autoencoder likelihood and the Counter-Hypothetical classifier."""
