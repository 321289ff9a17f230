"""What a measurement gives to look at: its tables and documents written, its frames drawn (annotate)."""
