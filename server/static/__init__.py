"""Files the app serves as they are (pages without a build step)."""
