"""Deformable registration (the virtual fixture): GB-CICP (paper Section 6.4), the
baselines NICP, CPD and RBF-FEM, their common result and the method registry."""
