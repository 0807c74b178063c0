"""
Studies of the paper's claims: the claims checked on reproduced figures under each protocol (``claims``,
``study_runs``), and the comparison of eq. 9 with other confidence bounds on the same tuning budget
(``beyond``, ``beyond_report``, ``tuning``).
"""
