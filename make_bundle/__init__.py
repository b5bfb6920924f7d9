"""chpf-make-bundle: one command from an object mesh to a model bundle and its report."""
