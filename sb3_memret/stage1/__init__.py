"""Stage 1: expert demonstrations, a learned controller finetuned on them, and serving controllers."""
