"""The STEP nominal (``qifreport.step``): the B-rep read through OpenCASCADE (OCP) with its
semantic PMI read from the Part 21 text (:mod:`.semantic`, beside XDE), tessellated with one
B-rep face id per triangle (:mod:`.tessellate`), and an AP242 writer for samples
(:mod:`.write`). Imports nothing of the other layers but the foundation."""
