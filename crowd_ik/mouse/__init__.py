"""`crowd-ik mouse`: one character posed with the mouse, and its drawing."""
