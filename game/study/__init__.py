"""The user study: protocols and their trials, the window's study session and questionnaires, Table 6.1, the
participant register, validity studies, blinded rating and agreement, and the study's pages on the records server.
"""
