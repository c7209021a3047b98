"""Playing and scoring episodes: a frozen controller under a prompt condition (``rollout``), many such episodes over
several envs served by one controller (``parallel``), and a trained memory's held-out retrieval and success
(``retrieval``)."""
