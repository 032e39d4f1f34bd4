// Sortable tables: a click on a header sorts the rows by that column (numbers as numbers, from a
// cell's data-v where it has one; cells without a value, "" or "-", last), a second click reverses.
document.querySelectorAll("table.sortable").forEach((table) => {
  const heads = table.tHead.rows[0].cells;
  const key = (row, col) => {
    const cell = row.cells[col];
    const raw = cell.dataset.v !== undefined ? cell.dataset.v : cell.textContent.trim();
    if (raw === "" || raw === "-") return null;
    const num = Number(raw.replace(/,/g, ""));
    return Number.isNaN(num) ? raw : num;
  };
  Array.from(heads).forEach((th, col) => th.addEventListener("click", () => {
    const asc = th.dataset.dir !== "asc";
    Array.from(heads).forEach((h) => delete h.dataset.dir);
    th.dataset.dir = asc ? "asc" : "desc";
    const body = table.tBodies[0];
    Array.from(body.rows).sort((a, b) => {
      const x = key(a, col), y = key(b, col);
      if (x === null || y === null) return (x === null) - (y === null);
      const order = typeof x === "number" && typeof y === "number" ? x - y : String(x).localeCompare(String(y));
      return asc ? order : -order;
    }).forEach((row) => body.appendChild(row));
  }));
});
