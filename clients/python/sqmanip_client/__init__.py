"""SQManip client SDK."""
