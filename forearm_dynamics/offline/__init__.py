"""Offline evaluation of recordings: check_bag's checks, scores, regression and delivery
figures, the HTML report, and bag_torques' batch torques."""
