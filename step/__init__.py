"""STEP AP242 nominal with semantic PMI (OCP/OpenCASCADE). Not yet implemented: see issue 3."""
