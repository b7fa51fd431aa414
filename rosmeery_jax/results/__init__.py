"""What a session leaves behind: its result tables, their plots, and the statistics over
seeds that the summaries and the paper tables print."""
