# The lines between ```cpp and ``` fences of a Markdown page (sed -n -f).
/^```cpp$/,/^```$/{
/^```/d
p
}
