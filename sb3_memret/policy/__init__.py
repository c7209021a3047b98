"""The memory learner: Plackett-Luce retrieval, the retriever and retention networks."""
