"""
The paper's figures (section 4, Figures 1-8), one module each, and what they write: the options every
figure takes (``reproduction``), its CSV, PNG and JSON (``reporting``) and its drawings (``figures``).
"""
