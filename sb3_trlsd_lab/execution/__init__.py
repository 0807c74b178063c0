"""
How the lab runs TRLSD: one run at a time (``runner``) or R runs of one method in lockstep
(``lockstep``, ``env_batches``, ``batches``), under a protocol (``protocols``), as jobs spread over
processes or a Ray cluster (``backends``, ``jobs``), their results kept on disk (``run_cache``).
"""
