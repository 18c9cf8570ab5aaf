"""What people look at: rerun views, figures (PNG) and table exports."""
