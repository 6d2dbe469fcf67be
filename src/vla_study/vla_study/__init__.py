"""The paper's user study (Section 7): human-like simulated participants, the protocol, the runner and
the analysis. See docs/study.md."""
